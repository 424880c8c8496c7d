"""Feature extractor for padded point sets with masks (a small PointNet).

SB3's default ``CombinedExtractor`` flattens ``points`` (N_max, 7): the policy
then sees slot order, which is arbitrary, and zero padding as real points. Here
each set key ``K`` with a mask ``K_mask`` goes through a shared per-point MLP and
a masked max- and mean-pool (permutation invariant, padding ignored); every
other Box key is flattened. Inputs are scaled to order one first:
x, y / 50 m, radial velocity / 30 m/s, amplitude -> log10(1 + a) / 3, range and
angle std -> log10(std) / 6 (std floored at 1e-6), radar index / 3. A point set
with fewer columns (policies trained on x, y, radial velocity, amplitude) uses the
first scales only.
The SLAM's Doppler ``velocity`` (when the env adds it) is scaled by 30 m/s, 5 m/s and 0.5 rad/s.
Of the SLAM ``pose`` only the lateral offset y and the heading are used: the
along-road x grows without bound over an episode (about 1 km in 40 s) and says
nothing about the traffic around the vehicle.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

__all__ = [
    "BOX_COLUMNS", "BOX_SCALES", "FEATURE_EXTRACTORS", "GridExtractor", "PointSetExtractor", "SET_SCALES", "box_layout",
]

# per-column scale of known set keys (x, y, radial velocity, amplitude, range std, angle std, radar)
# and (x, y): a number divides, None is log10(1 + a) / 3, "log" is log10(max(x, 1e-6)) / 6
SET_SCALES = {"points": (50.0, 50.0, 30.0, None, "log", "log", 3.0), "landmarks": (50.0, 50.0)}
BOX_SCALES = {"pose": (100.0, 10.0, np.pi), "pose_std": (5.0, 5.0, 0.5), "velocity": (30.0, 5.0, 0.5)}
# columns of a Box key that the extractor uses (default: all)
BOX_COLUMNS = {"pose": (1, 2)}


def _scale_set(key: str, x: torch.Tensor) -> torch.Tensor:
    scales = SET_SCALES.get(key)
    if scales is None:
        return x
    cols = []
    for j, s in enumerate(scales[: x.shape[-1]]):
        col = x[..., j]
        if s is None:
            cols.append(torch.log10(1.0 + col.clamp(min=0.0)) / 3.0)
        elif s == "log":
            cols.append(torch.log10(col.clamp(min=1e-6)) / 6.0)
        else:
            cols.append(col / float(s))
    return torch.stack(cols, dim=-1)


def box_layout(space: gym.spaces.Dict) -> dict[str, slice]:
    """The columns of each Box key (every key that is neither a set ``K`` with a ``K_mask`` nor a mask) in the
    vector :class:`PointSetExtractor`'s box layer reads, in the space's key order."""
    out, at = {}, 0
    for k in space.spaces:
        if not k.endswith("_mask") and f"{k}_mask" not in space.spaces:
            width = PointSetExtractor._box_width(k, space[k])
            out[k], at = slice(at, at + width), at + width
    return out


class PointSetExtractor(BaseFeaturesExtractor):
    """Masked PointNet over every ``K`` / ``K_mask`` pair, concatenated with the flattened other keys."""

    def __init__(self, observation_space: gym.spaces.Dict, point_dim: int = 64, box_dim: int = 32):
        set_keys = [k for k in observation_space.spaces if f"{k}_mask" in observation_space.spaces]
        layout = box_layout(observation_space)
        box_keys = list(layout)
        total = 2 * point_dim * len(set_keys) + (box_dim if box_keys else 0)
        super().__init__(observation_space, features_dim=total)
        self.set_keys, self.box_keys = set_keys, box_keys
        self.point_nets = nn.ModuleDict(
            {
                k: nn.Sequential(
                    nn.Linear(_shape(observation_space[k])[-1], point_dim),
                    nn.ReLU(),
                    nn.Linear(point_dim, point_dim),
                    nn.ReLU(),
                )
                for k in set_keys
            }
        )
        box_in = sum(cols.stop - cols.start for cols in layout.values())
        self.box_net = nn.Sequential(nn.Linear(box_in, box_dim), nn.ReLU()) if box_keys else None

    @staticmethod
    def _box_width(key: str, space: gym.spaces.Space) -> int:
        width = int(np.prod(_shape(space)))
        cols = BOX_COLUMNS.get(key)
        return len(cols) if cols is not None and space.shape == (len(BOX_SCALES.get(key, ())),) else width

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        feats = []
        for k in self.set_keys:
            x, mask = _used_slots(obs[k], obs[f"{k}_mask"])
            x = _scale_set(k, x.float())
            mask = mask.float().unsqueeze(-1)  # (B, N', 1)
            h = self.point_nets[k](x)  # (B, N, D)
            count = mask.sum(dim=1).clamp(min=1.0)
            mean = (h * mask).sum(dim=1) / count
            # masked max; an empty set gives zeros, not -inf
            maxed = torch.where(mask > 0, h, torch.full_like(h, -1e9)).max(dim=1).values
            maxed = torch.where(mask.sum(dim=1) > 0, maxed, torch.zeros_like(maxed))
            feats += [maxed, mean]
        if self.box_net is not None:
            feats.append(self.box_net(_box_features(obs, self.box_keys)))
        return torch.cat(feats, dim=1)


def _used_slots(points: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``points`` (B, N, F) and ``mask`` (B, N) cut after the last slot any set of the batch uses (at least one slot).

    The envs fill a set from its first slot (~40 of the 256 point slots per scan): the per-point MLP then runs on
    the used slots only (4-6x less work in PPO's updates). The pooled features are those of the full sets: a
    padded slot weighs nothing in the masked mean and never wins the masked max (the mean's float32 sum may
    differ in its last bit, its order of summation being another).
    """
    used = torch.nonzero(mask.reshape(mask.shape[0], -1).any(dim=0))
    n = int(used[-1, 0]) + 1 if used.numel() else 1
    return points[:, :n], mask[:, :n]


def _box_features(obs: dict[str, torch.Tensor], keys: list[str]) -> torch.Tensor:
    """The flattened, scaled Box keys (``BOX_SCALES`` / ``BOX_COLUMNS``), concatenated."""
    parts = []
    for k in keys:
        v = obs[k].float().flatten(1)
        s = BOX_SCALES.get(k)
        if s is not None and v.shape[1] == len(s):
            v = v / torch.tensor(s, dtype=v.dtype, device=v.device)
            cols = BOX_COLUMNS.get(k)
            if cols is not None:
                v = v[:, list(cols)]
        parts.append(v)
    return torch.cat(parts, dim=1)


class GridExtractor(BaseFeaturesExtractor):
    """Ego-centred bird's-eye grid of the point cloud and the SLAM map, then a small CNN.

    Cells of ``cell_m`` x ``cell_m`` over x in [``x_min_m``, ``x_max_m``) (forward)
    and y in [-``half_width_m``, ``half_width_m``) (vehicle frame, m). Channels per cell:

    * points: log(1 + n) with n the number of radar points in the cell;
    * mean radial velocity of those points / 30 m/s (0 where empty): Doppler tells
      a vehicle keeping pace (~0) from a static landmark (~ -ego speed) or a closing one;
    * landmarks (when the observation has them): log(1 + n) of SLAM map landmarks.

    Points outside the grid and padded slots (mask 0) are dropped, so the grid
    is invariant to slot order and padding. Rasterised with ``index_add_`` (no
    loop over points). Box keys (SLAM lateral offset and heading, pose std) are
    scaled as in :class:`PointSetExtractor` and concatenated after the CNN.
    """

    def __init__(
        self,
        observation_space: gym.spaces.Dict,
        cell_m: float = 2.0,
        x_min_m: float = -30.0,
        x_max_m: float = 70.0,
        half_width_m: float = 12.0,
        cnn_dim: int = 128,
        box_dim: int = 32,
    ):
        if not (cell_m > 0 and x_max_m > x_min_m and half_width_m > 0):
            raise ValueError("GridExtractor needs cell_m > 0, x_max_m > x_min_m and half_width_m > 0")
        spaces = observation_space.spaces
        if "points" not in spaces or "points_mask" not in spaces:
            raise ValueError("GridExtractor needs 'points' and 'points_mask' observations")
        box_keys = [k for k in spaces if k not in ("points", "landmarks") and not k.endswith("_mask")]
        super().__init__(observation_space, features_dim=cnn_dim + (box_dim if box_keys else 0))
        self.cell, self.x0, self.y0 = float(cell_m), float(x_min_m), -float(half_width_m)
        self.nx = int(np.ceil((x_max_m - x_min_m) / cell_m))
        self.ny = int(np.ceil(2 * half_width_m / cell_m))
        self.use_landmarks = "landmarks" in spaces and "landmarks_mask" in spaces
        self.box_keys = box_keys
        channels = 3 if self.use_landmarks else 2
        self.cnn = nn.Sequential(
            nn.Conv2d(channels, 16, 3, padding=1), nn.ReLU(),
            nn.Conv2d(16, 32, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1), nn.ReLU(),
            nn.Flatten(),
        )  # fmt: skip
        with torch.no_grad():
            width = self.cnn(torch.zeros(1, channels, self.ny, self.nx)).shape[1]
        self.head = nn.Sequential(nn.Linear(width, cnn_dim), nn.ReLU())
        box_in = sum(PointSetExtractor._box_width(k, spaces[k]) for k in box_keys)
        self.box_net = nn.Sequential(nn.Linear(box_in, box_dim), nn.ReLU()) if box_keys else None

    def _scatter(self, xy: torch.Tensor, mask: torch.Tensor, values: torch.Tensor | None):
        """Per-cell count (and sum of ``values``) of the masked points (B, N, 2) -> (B, ny, nx)."""
        b = xy.shape[0]
        ix = torch.floor((xy[..., 0] - self.x0) / self.cell).long()
        iy = torch.floor((xy[..., 1] - self.y0) / self.cell).long()
        ok = (mask > 0) & (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        batch = torch.arange(b, device=xy.device).unsqueeze(1).expand_as(ix)
        flat = (batch * self.ny + iy) * self.nx + ix
        flat, w = flat[ok], ok[ok].float()
        count = torch.zeros(b * self.ny * self.nx, device=xy.device).index_add_(0, flat, w)
        total = None
        if values is not None:
            total = torch.zeros_like(count).index_add_(0, flat, values.float()[ok])
            total = total.view(b, self.ny, self.nx)
        return count.view(b, self.ny, self.nx), total

    def grid(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        """The (B, C, ny, nx) grid of an observation batch (rows: y from -half_width up; columns: x)."""
        pts = obs["points"].float()
        count, vsum = self._scatter(pts[..., :2], obs["points_mask"], pts[..., 2])
        chans = [torch.log1p(count), torch.where(count > 0, vsum / count.clamp(min=1.0), 0.0) / 30.0]
        if self.use_landmarks:
            lm, _ = self._scatter(obs["landmarks"].float(), obs["landmarks_mask"], None)
            chans.append(torch.log1p(lm))
        return torch.stack(chans, dim=1)

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        feats = [self.head(self.cnn(self.grid(obs)))]
        if self.box_net is not None:
            feats.append(self.box_net(_box_features(obs, self.box_keys)))
        return torch.cat(feats, dim=1)


def _shape(space: gym.spaces.Space) -> tuple[int, ...]:
    """The shape of a Box / MultiBinary space (every space this extractor reads has one)."""
    if space.shape is None:
        raise ValueError(f"space {space} has no shape")
    return space.shape


FEATURE_EXTRACTORS = {"point_set": PointSetExtractor, "grid": GridExtractor}
