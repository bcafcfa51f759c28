"""A small LeRobot ACT policy saved as LeRobot saves one: state + environment state in, 50-step chunks out.

Built with torch and LeRobot (import this only where both are installed); nothing is downloaded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.act.configuration_act import ACTConfig
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.factory import make_pre_post_processors


def save_small_act(folder: Path, home: np.ndarray, state_std: float, dim_model: int = 64,
                   n_encoder_layers: int = 1) -> Path:
    """An untrained ACT whose normalised actions sit near ``home`` (policy units), with its processors."""
    torch.manual_seed(0)
    config = ACTConfig(
        input_features={"observation.state": PolicyFeature(FeatureType.STATE, (6,)),
                        "observation.environment_state": PolicyFeature(FeatureType.ENV, (6,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (6,))},
        chunk_size=50, n_action_steps=50, dim_model=dim_model, dim_feedforward=4 * dim_model,
        n_encoder_layers=n_encoder_layers, n_decoder_layers=1, use_vae=False, pretrained_backbone_weights=None,
        device="cpu")
    mean = torch.tensor(home, dtype=torch.float32)
    stats = {"observation.state": {"mean": mean, "std": torch.full((6,), state_std)},
             "observation.environment_state": {"mean": torch.zeros(6), "std": torch.ones(6)},  # camera [m]
             "action": {"mean": mean, "std": torch.full((6,), 0.5)}}  # near home, in the policy's units
    pre, post = make_pre_post_processors(config, dataset_stats=stats)
    ACTPolicy(config).save_pretrained(folder)
    pre.save_pretrained(folder)
    post.save_pretrained(folder)
    return folder
