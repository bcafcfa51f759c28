"""Recovery behaviours: every module of this package that defines one (a ``Recovery`` with its
``do: Literal["a_name"]``) is found here, so a new behaviour is one new file; ``RECOVERIES`` maps a behaviour's
name to its class.

A scenario's ``recovery:`` section (``RecoveryPolicy``) says which failed check starts which
behaviour, how many attempts it gets and what it escalates to.
"""

from typing import Annotated, Union

from pydantic import Field

from cellguard.robot.kinds import discover
from cellguard.robot.recovery.base import Plan, Recovery
from cellguard.robot.recovery.policy import RecoveryPolicy

# the order a scenario's error for an unknown name has listed the behaviours in; behaviours added later follow by name
_LISTED = ("retry_grasp", "back_off", "rehome", "reregister_datum", "operator")
RECOVERIES: dict[str, type[Recovery]] = discover(__name__, __path__, Recovery, "recovery behaviour", tag="do",
                                                 first=_LISTED)
AnyRecovery = Annotated[Union[tuple(RECOVERIES.values())], Field(discriminator="do")]  # noqa: UP007
RecoveryPolicy.model_rebuild(_types_namespace={"AnyRecovery": AnyRecovery})

__all__ = ["RECOVERIES", "AnyRecovery", "Plan", "Recovery", "RecoveryPolicy"]
