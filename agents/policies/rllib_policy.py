"""A trained RLlib checkpoint as a policy: what ``rhs-slam evaluate`` / ``demo`` load from ``rhs-slam train --backend
rllib`` (:mod:`agents.algos.rllib` trains; this module only reads, so evaluation never imports the trainer).

:class:`RLlibPolicy` rebuilds the RLModule of ``DIR/rllib_checkpoint`` and runs it behind the
``predict(obs, deterministic)`` interface of stable-baselines3 models; a module trained with a privileged
critic (:class:`agents.algos.rllib.PointSetPPOModule`) acts on the observation without the privileged key.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np

__all__ = ["CHECKPOINT_DIR", "MODULE_SUBDIR", "RLlibPolicy", "is_rllib_checkpoint", "require_ray"]

CHECKPOINT_DIR = "rllib_checkpoint"
#: the RLModule inside an algorithm checkpoint (single-agent: the default module id)
MODULE_SUBDIR = ("learner_group", "learner", "rl_module", "default_policy")


def require_ray():
    """Import ray, or raise ``ValueError`` telling how to install the extra."""
    try:
        import ray
        from ray.rllib.algorithms.ppo import PPOConfig  # noqa: F401
    except ImportError as exc:
        raise ValueError(
            f"the rllib backend needs Ray RLlib ({exc}): pip install torch==2.13.0 && pip install -e '.[rllib]'"
        ) from None
    return ray


def is_rllib_checkpoint(path: str | Path) -> bool:
    """A directory holding an RLlib algorithm checkpoint (or its RLModule)."""
    p = Path(path)
    return p.is_dir() and (p.joinpath(*MODULE_SUBDIR).is_dir() or (p / "class_and_ctor_args.pkl").exists())


class RLlibPolicy:
    """The RLModule of an RLlib checkpoint behind the ``predict(obs, deterministic)`` interface of SB3 models.

    Needs only torch and ray.rllib (no Ray cluster): the module is rebuilt from
    the checkpoint and run on one observation at a time; ``deterministic``
    takes the arg-max action, else samples the categorical distribution.
    """

    def __init__(self, path: str | Path):
        require_ray()
        from ray.rllib.core.rl_module.rl_module import RLModule

        p = Path(path)
        module_dir = p.joinpath(*MODULE_SUBDIR) if p.joinpath(*MODULE_SUBDIR).is_dir() else p
        self.module = RLModule.from_checkpoint(str(module_dir.resolve()))
        self.module.eval()
        space = self.module.observation_space
        if isinstance(space, gym.spaces.Dict):  # the actor never reads a privileged critic's key
            from agents.policies.privileged import without_privileged

            space = without_privileged(space)
        self.observation_space = space
        self.action_space = self.module.action_space

    def predict(self, obs, deterministic: bool = True):
        import torch

        def batch1(x):
            return torch.as_tensor(np.asarray(x))[None]

        o = {k: batch1(v) for k, v in obs.items()} if isinstance(obs, dict) else batch1(obs)
        with torch.no_grad():
            logits = self.module.forward_inference({"obs": o})["action_dist_inputs"][0]
        if deterministic:
            return int(torch.argmax(logits)), None
        return int(torch.distributions.Categorical(logits=logits).sample()), None
