"""Track health of the SLAM: is the filter still where the map says it is, and does it know?

A particle filter that has lost the car keeps reporting a tight particle cloud: after a
wrong motion (a failed registration, a collision) every observation starts a new landmark,
the map is rebuilt around the wrong pose and the filter is self-consistent again, far from
the truth. :class:`TrackHealth` watches the signs of such a loss and latches it.

Per cycle, three scores in [0, 1] (1 = healthy):

* **match**: ``f = n_matched / n_observations`` (the particles' mean matches over the clustered
  observations) while the map holds at least ``min_landmarks`` landmarks and the cycle has at
  least 3 observations; ``h_match = clip((f - f_lost) / (f_ok - f_lost), 0, 1)``. On a forward
  drive new landmarks keep entering the view, so a healthy filter matches a part, not all.
  Without that evidence the score holds its last value.
* **registration**: the fraction ``g`` of the current static points within the registration's
  gate of a previous point after the fit; ``h_reg = clip(g / g_ok, 0, 1)``, halved when the fit's
  translation failed the Doppler gate (:class:`slam.core.pipeline.PipelineConfig`).
* **dead reckoning**: after ``blind_cycles_ok`` consecutive cycles whose registration measured
  nothing (too few points, no pair), the score falls by ``1 / blind_cycles_ok`` per further cycle:
  the heading then comes from the last turn rate alone, and a lane change reverses it within
  a cycle (0.4 rad, 2 m across the road per 5 m driven).
* **spread**: the particles' position std ``s = hypot(s_x, s_y)`` (m):
  ``h_spread = clip((s_lost - s) / (s_lost - s_ok), 0, 1)``.
* **anchor**: after ``unanchored_cycles_ok`` consecutive cycles in which no observation was associated
  with a map landmark (the particles' mean matches is 0), the score falls by ``1 / unanchored_cycles_ok``
  per further cycle: the pose then comes from the odometry alone, whatever the other scores say (a scene
  with nothing static, where the registration may still pair the points of cars). With
  :attr:`TrackHealth.static_scene` False (the owner knows the scene holds nothing static: the SLAM wrapper
  on a road without landmarks or obstacles) no cycle counts as associated, a match being one with a moving
  car. A new map keeps the count (an empty map matches nothing); a relocalisation, a match with the old map,
  clears it. On the straight-road drives a cycle without a match is the first of a map only.

``health = min(h_match, h_reg, h_blind, h_spread, h_anchor)``. A cycle whose health is below ``lost_below``
starts a **loss**. ``lost_below`` = 0.7: on the tuning drives (highway and dense, IDM, the shipped policy
and random actions, seeds 1000-1029) no cycle with an error below 0.5 m scored below 0.8, while a sharp
lane change that matched a quarter of the observations (health 0.57) left a 0.015 rad heading error
that the drive turned into 5-9 m unflagged (0.25, the earlier bound, missed it; flagged, the
relocalisation corrects it in the same cycle): ``lost`` is set and stays set (the pose in the map frame is off by an
unknown amount) until the filter relocalises against the map built before the loss
(:meth:`TrackHealth.relocalised`) or a new map starts (:meth:`TrackHealth.new_map`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rhs_common.validation import check_int, check_range, check_types

__all__ = ["HealthConfig", "TrackHealth"]


@dataclass(frozen=True)
class HealthConfig:
    """Thresholds of :class:`TrackHealth` (fractions in [0, 1], stds in m).

    ``match_lost`` < ``match_ok``: matched fractions scored 0 and 1; ``fit_ok`` (0, 1]: the
    registration fit fraction scored 1; ``blind_cycles_ok`` [1, 1000]: cycles without a registration
    fit scored 1; ``spread_ok_m`` < ``spread_lost_m``: position stds scored
    1 and 0; ``lost_below`` [0, 1]: a health below this starts a loss; ``min_landmarks`` [0, 10^6]:
    map landmarks needed before the matched fraction counts; ``unanchored_cycles_ok`` [1, 1000]: consecutive
    cycles without an observation associated with the map scored 1.
    """

    match_lost: float = 0.1
    match_ok: float = 0.35
    fit_ok: float = 0.3
    blind_cycles_ok: int = 1
    spread_ok_m: float = 2.5
    spread_lost_m: float = 6.0
    lost_below: float = 0.7
    min_landmarks: int = 5
    unanchored_cycles_ok: int = 3

    def __post_init__(self) -> None:
        check_types(self)
        check_range("match_lost", self.match_lost, 0.0, 1.0)
        check_range("match_ok", self.match_ok, self.match_lost, 1.0, low_open=True)
        check_range("fit_ok", self.fit_ok, 0.0, 1.0, low_open=True)
        check_int("blind_cycles_ok", self.blind_cycles_ok, 1, 1000)
        check_range("spread_ok_m", self.spread_ok_m, 0.0, 1e6)
        check_range("spread_lost_m", self.spread_lost_m, self.spread_ok_m, 1e6, low_open=True)
        check_range("lost_below", self.lost_below, 0.0, 1.0)
        check_int("min_landmarks", self.min_landmarks, 0, 1_000_000)
        check_int("unanchored_cycles_ok", self.unanchored_cycles_ok, 1, 1000)


def _clip01(x: float) -> float:
    return min(max(x, 0.0), 1.0)


class TrackHealth:
    """Per-cycle health score and the latched ``lost`` flag (module docstring)."""

    def __init__(self, config: HealthConfig | None = None) -> None:
        self.config = config if config is not None else HealthConfig()
        #: the scene holds static features the map can anchor to (the owner sets it; False: no match counts)
        self.static_scene = True
        self.reset()

    def reset(self) -> None:
        """A new map: healthy, not lost, no loss so far."""
        self.h_match = 1.0
        self.h_reg = 1.0
        self.h_spread = 1.0
        self.h_blind = 1.0
        self.blind = 0  # consecutive cycles without a registration fit
        self.h_anchor = 1.0
        self.unanchored = 0  # consecutive cycles without an observation associated with the map
        self.health = 1.0
        self.lost = False
        self.losses = 0  # losses started since the reset
        self.lost_cycles = 0  # cycles since the current loss started (0 when not lost)
        self.loss_landmark_id = -1  # landmarks with a smaller id were mapped before the current loss

    def update(
        self,
        n_observations: int,
        n_matched: float,
        map_landmarks: int,
        fit_fraction: float | None,
        registered: bool,
        gated: bool,
        position_std_m: float,
        next_landmark_id: int,
    ) -> float:
        """Score one cycle; returns the health. ``fit_fraction`` None: no fit to score; ``registered``: the
        registration measured the motion (point pairs), not only returned its guess."""
        c = self.config
        if map_landmarks >= c.min_landmarks and n_observations >= 3:
            f = n_matched / n_observations
            self.h_match = _clip01((f - c.match_lost) / (c.match_ok - c.match_lost))
        if fit_fraction is not None:
            self.h_reg = _clip01(fit_fraction / c.fit_ok) * (0.5 if gated else 1.0)
        self.blind = 0 if registered else self.blind + 1
        self.h_blind = _clip01(1.0 - (self.blind - c.blind_cycles_ok) / c.blind_cycles_ok)
        s = position_std_m if math.isfinite(position_std_m) else c.spread_lost_m
        self.h_spread = _clip01((c.spread_lost_m - s) / (c.spread_lost_m - c.spread_ok_m))
        self.unanchored = 0 if self.static_scene and n_matched > 0 else self.unanchored + 1
        k = c.unanchored_cycles_ok
        self.h_anchor = _clip01(1.0 - (self.unanchored - k) / k)
        self.health = min(self.h_match, self.h_reg, self.h_blind, self.h_spread, self.h_anchor)
        if self.lost:
            self.lost_cycles += 1
        elif self.health < c.lost_below:
            self.lost = True
            self.losses += 1
            self.lost_cycles = 1
            self.loss_landmark_id = int(next_landmark_id)
        return self.health

    def relocalised(self) -> None:
        """The filter found itself again in the map built before the loss."""
        self.lost = False
        self.lost_cycles = 0
        self.h_match = self.h_reg = self.h_spread = self.h_blind = self.h_anchor = self.health = 1.0
        self.blind = self.unanchored = 0

    def new_map(self) -> None:
        """A new map started at the current estimate (a break in the map frame): not lost in it. The cycles
        without an association carry on (an empty map anchors nothing), and so does their score."""
        losses, unanchored, h_anchor = self.losses, self.unanchored, self.h_anchor
        self.reset()
        self.losses, self.unanchored, self.h_anchor = losses, unanchored, h_anchor
        self.health = h_anchor
