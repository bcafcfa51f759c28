"""Recovery behaviours, registered in one place: ``RECOVERIES`` maps a behaviour's name to its class.

A scenario's ``recovery:`` section (``RecoveryPolicy``) says which failed check starts which
behaviour, how many attempts it gets and what it escalates to.
"""

from typing import Annotated, Union

from pydantic import Field

from cellguard.robot.recovery.back_off import BackOff
from cellguard.robot.recovery.base import Plan, Recovery
from cellguard.robot.recovery.operator import Operator
from cellguard.robot.recovery.policy import RecoveryPolicy
from cellguard.robot.recovery.rehome import Rehome
from cellguard.robot.recovery.reregister_datum import ReregisterDatum
from cellguard.robot.recovery.retry_grasp import RetryGrasp

_KINDS = (RetryGrasp, BackOff, Rehome, ReregisterDatum, Operator)
RECOVERIES: dict[str, type[Recovery]] = {k.model_fields["do"].annotation.__args__[0]: k for k in _KINDS}
AnyRecovery = Annotated[Union[_KINDS], Field(discriminator="do")]  # noqa: UP007
RecoveryPolicy.model_rebuild(_types_namespace={"AnyRecovery": AnyRecovery})

__all__ = ["RECOVERIES", "AnyRecovery", "Plan", "Recovery", "RecoveryPolicy"]
