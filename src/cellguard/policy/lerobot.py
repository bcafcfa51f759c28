"""LeRobot adapter (``lerobot:DIR``): any ``PreTrainedPolicy`` with its pre- and post-processors.

``DIR`` is what ``policy.save_pretrained(DIR)`` and the processors' ``save_pretrained(DIR)``
wrote. The batch holds ``observation.state`` (1, A) in the policy's own space (through the
action map) and, when the policy takes it, ``observation.environment_state``: the cell's
measurements concatenated in the order the cell reports them. ``predict_action_chunk`` gives
(1, H, A); the post-processor un-normalises it. Nothing is downloaded: the weights are local.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from cellguard.embodiment.profile import SOFT_MARGIN
from cellguard.errors import ConfigError
from cellguard.policy.adapter import MappedPolicy, PolicyInputs, resolve_map, split_options, step_period

OPTIONS = {"map": "action map YAML file", "dt": "step period [s]", "task": "task text for language-conditioned policies"}
TAKES_FILE = True  # lerobot:DIR, a folder, frozen in a release by its absolute path (cellguard.policy.registry)


class LeRobotBackend:
    """A LeRobot policy on the CPU, fed through its own processor pipelines."""

    def __init__(self, policy, preprocessor, postprocessor, content_hash: str):
        import torch

        self._torch = torch
        self.policy, self.pre, self.post = policy.eval(), preprocessor, postprocessor
        features = policy.config.output_features
        if "action" not in features:
            raise ConfigError(f"policy: lerobot: the policy has no 'action' output; outputs: {', '.join(features)}")
        self.action_dim = int(features["action"].shape[0])
        self.action_names = None
        self.embedded_map = None
        self.dt_s = None  # a saved policy states no control period: the source gives ?dt=
        self._environment = "observation.environment_state" in policy.config.input_features
        self._hash = content_hash

    def infer(self, inputs: PolicyInputs) -> np.ndarray:
        torch = self._torch
        batch = {"observation.state": torch.as_tensor(np.asarray(inputs.state, np.float32))[None]}
        if self._environment:
            env = np.concatenate([np.ravel(v) for v in inputs.measurements.values()]).astype(np.float32)
            batch["observation.environment_state"] = torch.as_tensor(env)[None]
        if inputs.task:
            batch["task"] = [inputs.task]
        with torch.inference_mode():
            chunk = self.policy.predict_action_chunk(self.pre(batch))
            chunk = self.post(chunk)
        return chunk[0].detach().cpu().numpy().astype(np.float64)

    def reset(self) -> None:
        self.policy.reset()

    def content_hash(self) -> str:
        return self._hash


def load_backend(folder: Path) -> LeRobotBackend:
    """Load policy and processors saved in ``folder`` (config.json, model.safetensors, processors)."""
    try:
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    except ImportError:
        raise ConfigError("policy: lerobot: needs LeRobot; install it with pip install 'cellguard[lerobot]' "
                          "(several GB: it brings torch)") from None
    folder = Path(folder)
    if not (folder / "config.json").is_file():
        raise ConfigError(f"policy: lerobot:{folder}: no config.json; expected a folder written by save_pretrained")
    config = PreTrainedConfig.from_pretrained(str(folder))
    config.device = "cpu"
    policy = get_policy_class(config.type).from_pretrained(str(folder), config=config)
    pre, post = make_pre_post_processors(config, pretrained_path=str(folder),
                                         preprocessor_overrides={"device_processor": {"device": "cpu"}})
    digest = hashlib.sha256()
    for path in sorted(folder.iterdir()):
        if path.is_file():
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return LeRobotBackend(policy, pre, post, digest.hexdigest())


def make_lerobot_policy(arg: str, cell, soft_margin: float = SOFT_MARGIN) -> MappedPolicy:
    """``lerobot:DIR?dt=0.0333[&map=FILE&task=...]`` for ``cell``."""
    target, options = split_options(arg, OPTIONS, "lerobot")
    backend = load_backend(Path(target))
    source = f"lerobot:{target}"
    amap = resolve_map(backend, cell, options.get("map"), source)
    dt = step_period(backend, options, source)
    return MappedPolicy(backend, amap, cell, source, dt, task=options.get("task", ""), soft_margin=soft_margin)
