"""Calibration of the fast radar (:mod:`rhs_env.fast_radar`) on the exact radar's *measured* detector.

The exact radar (:class:`rhs_env.radar.RadarSystem`) synthesises every searched range bin of every beam slot,
detects with the footprint OS-CFAR and estimates angle, Doppler and sub-bin range by OMP. Its real
noise-only false-alarm rate is not the design ``P_fa`` (0.7-0.8x), and what it makes of two scatterers in one
cell is not a formula; so the fast radar draws from what the exact one was *measured* to do, scan by scan, on
the project's highway scenes:

* every visible (radar, scatterer) pair gets its expected coherent SNR, the SNR of the point's amplitude ``a``
  of an isolated target: ``a^2 = unit_gain_snr(R, sigma) ||h(theta)||^2`` (link budget, two-way pattern over the
  slots; :meth:`rhs_env.radar_config.RadarConfig.unit_gain_snr`);
* the points of radar r are matched to its visible pairs: each point to the nearest pair within ``gate_m``
  (vehicle frame). A pair with a point is *detected*; its first (nearest) point gives the estimate errors
  (range, angle, radial velocity, log amplitude over the expected); further points on the same pair are
  *extra* points (a target split by the OMP); a point with no pair within the gate is a *false* point
  (sidelobes, split or displaced points, noise alarms); within :data:`LINK_M` of a pair it is *linked* to the
  nearest one and kept as its offset from that pair (range, angle, velocity, log amplitude), else it is *free* and
  kept with its radar, range, angle, velocity and amplitude;
* by SNR bin and scatterer class (moving / static: vehicles' faces share cells, landmarks mostly do not) the
  table holds ``P_d``, the extra-point rate, a pool of measured error vectors and the linked false points per
  visible pair (with a pool of their offsets per class); the free false points per scan and a pool of them.

:class:`FastRadarTable` is the table (a small ``.npz``); :func:`table_key` names it by the radar settings it
depends on (everything but the kernels, the synthesis path and the uncertainty floors, which the fast radar
applies itself); :func:`load_table` finds it shipped in ``rhs_env/data`` or in the user cache
(:func:`rhs_common.cache_dir.cache_subdir`); :func:`measure` and :func:`refine` make one
(:func:`rhs_env.fast_radar.calibrate`, ``scripts/calibrate_fast_radar.py``).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "ERROR_COLUMNS",
    "FALSE_COLUMNS",
    "FastRadarTable",
    "MissingCalibrationError",
    "ScanRecord",
    "TableBuilder",
    "cached_table_path",
    "calibration_scenes",
    "expected_snr",
    "extra_rate_of",
    "link_rate_of",
    "load_table",
    "match_scan",
    "measure",
    "pd_of",
    "refine",
    "shipped_table_path",
    "table_key",
]

#: columns of an error vector: range (m), angle (rad, wrapped), radial velocity (m/s), ln(a / a_expected)
ERROR_COLUMNS = ("range_m", "angle_rad", "velocity_mps", "log_amplitude")
#: columns of a false point: radar, range (m), angle from boresight (rad), radial velocity (m/s), amplitude
FALSE_COLUMNS = ("radar", "range_m", "angle_rad", "velocity_mps", "amplitude")
#: settings that do not change what the detector measures (left out of :func:`table_key`)
_KEY_EXCLUDED = ("kernels", "fidelity", "range_std_floor_m", "angle_std_floor_deg")
TABLE_VERSION = 2
#: a false point within this distance (vehicle frame) of a visible scatterer of its radar is *linked* to it
#: (a split or displaced point beside a target: most false points of the exact radar, and every ghost in the
#: ego's path measured, lie 1-3 m from a scatterer); farther ones are *free* (noise alarms)
LINK_M = 5.0
#: P_d bins: 2 dB of expected coherent SNR from -10 to 100 dB (clamped outside)
PD_EDGES_DB = np.arange(-10.0, 101.0, 2.0)
#: error-pool bins: 2 dB
ERR_EDGES_DB = PD_EDGES_DB
#: a pool bin with fewer measured errors borrows the nearest bin with at least this many
MIN_POOL = 40
DATA_DIR = Path(__file__).with_name("data")


class MissingCalibrationError(FileNotFoundError, ValueError):
    """No fast-radar table for these radar settings (a ``ValueError`` too: the settings are the user's choice)."""


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def table_key(config: Any) -> str:
    """12 hex digits naming a radar configuration's calibration (sha256 of its flat settings).

    Args:
        config: a :class:`rhs_env.radar_config.RadarConfig`.

    Returns:
        The key; the kernels, the synthesis path and the uncertainty floors do not enter it.
    """
    flat = {k: v for k, v in config.flat_dict().items() if k not in _KEY_EXCLUDED}
    text = json.dumps(flat, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def shipped_table_path(config: Any) -> Path:
    """Where the package ships the table of ``config`` (``rhs_env/data/fast_radar_<key>.npz``)."""
    return DATA_DIR / f"fast_radar_{table_key(config)}.npz"


def cached_table_path(config: Any) -> Path:
    """Where a table calibrated at first use is kept (the user cache's ``fast_radar`` folder)."""
    from rhs_common.cache_dir import cache_subdir

    return cache_subdir("fast_radar") / f"fast_radar_{table_key(config)}.npz"


def expected_snr(system: Any, radar: np.ndarray, range_m: np.ndarray, theta: np.ndarray,
                 rcs: np.ndarray) -> np.ndarray:
    """Expected coherent SNR ``a^2`` (linear) of isolated targets (radar, range, angle from boresight, RCS).

    Args:
        system: the :class:`rhs_env.radar.RadarSystem` (its dictionaries give the two-way gains).
        radar: (P,) radar index per pair.
        range_m: (P,) range, m.
        theta: (P,) angle from the radar's boresight, rad.
        rcs: (P,) radar cross-section, m^2.

    Returns:
        (P,) ``unit_gain_snr(R, sigma) ||h(theta)||^2``.
    """
    hn2 = np.zeros(radar.size)
    dics = system.dictionaries
    groups, gain, noise = _snr_constants(system)
    for radars in groups:
        if len(groups) == 1 and radar.size:  # one dictionary for every radar: every pair, no selection
            hn2 = np.sum(np.abs(dics[radars[0]].atoms(theta)[0]) ** 2, axis=0)
            break
        sel = np.isin(radar, radars)
        if np.any(sel):
            h = dics[radars[0]].atoms(theta[sel])[0]
            hn2[sel] = np.sum(np.abs(h) ** 2, axis=0)
    # RadarConfig.unit_gain_snr with its window gain and noise power kept (the same operations)
    return np.asarray(system.config.echo_power_w(range_m, rcs) * gain / noise, float) * hn2


def _snr_constants(system: Any) -> tuple[list[list[int]], float, float]:
    """The radars grouped by shared dictionary, the window gain ``C (sum w)^2 / sum w^2`` and ``sigma_n^2`` (W) of
    :meth:`rhs_env.radar_config.RadarConfig.unit_gain_snr`, computed once per system (and again when its config or
    dictionaries are replaced)."""
    from rhs_env.windows import make_window

    config, dics = system.config, system.dictionaries
    cached = system.__dict__.get("_snr_constants")
    if cached is not None and cached[0] is config and cached[1] == [id(d) for d in dics]:
        return cached[2]
    done: dict[int, list[int]] = {}
    for r, dic in enumerate(dics):
        done.setdefault(id(dic), []).append(r)
    wf = config.waveform
    w = make_window(wf.window, wf.samples).astype(float)
    gain = wf.chirps_per_slot * w.sum() ** 2 / np.sum(w ** 2)
    out = (list(done.values()), gain, config.noise_power_w)
    system.__dict__["_snr_constants"] = (config, [id(d) for d in dics], out)
    return out


@dataclass
class ScanRecord:
    """What one exact scan measured (:func:`match_scan`).

    Attributes:
        snr_db: (P,) expected SNR of every visible pair, dB.
        static: (P,) bool, the pair's scatterer is static.
        detected: (P,) bool.
        errors: (P, 4) :data:`ERROR_COLUMNS` (NaN where not detected).
        extra: (P,) int, further points matched to the pair.
        extra_errors: (X, 4) errors of those points.
        false_points: (F, 5) :data:`FALSE_COLUMNS`.
        false_xy: (F, 2) the false points in the vehicle frame.
        false_link: (F,) the pair a false point is linked to (:data:`LINK_M`), -1 for a free one.
        link_offsets: (F, 4) a linked false point's offset from its pair (:data:`ERROR_COLUMNS`), NaN when free.
        linked: (P,) linked false points per pair.
    """

    snr_db: np.ndarray
    static: np.ndarray
    detected: np.ndarray
    errors: np.ndarray
    extra: np.ndarray
    extra_errors: np.ndarray
    false_points: np.ndarray
    false_xy: np.ndarray
    false_link: np.ndarray
    link_offsets: np.ndarray
    linked: np.ndarray


def match_scan(system: Any, cloud: Any, scatterers: Any, occluders: Any, gate_m: float = 1.0) -> ScanRecord:
    """Match a scan's points to the visible (radar, scatterer) pairs (module docstring).

    Args:
        system: the radar that made ``cloud`` (exact or fast; its geometry is used).
        cloud: its :class:`rhs_env.point_cloud.PointCloud`.
        scatterers: the scan's :class:`rhs_env.scatterers.Scatterers`.
        occluders: the scan's :class:`rhs_env.scatterers.Occluders`.
        gate_m: matching gate in the vehicle frame, m.

    Returns:
        The :class:`ScanRecord`.
    """
    empty4 = np.zeros((0, 4))
    if len(scatterers):
        frame = system.radar_frame(scatterers.xy)
        rr, kk = np.nonzero(system.visible(scatterers, occluders, frame))
    else:
        frame, rr, kk = None, np.zeros(0, int), np.zeros(0, int)
    n_p = len(cloud)
    p_radar = np.asarray(cloud.radar, int)
    owner = np.full(n_p, -1)
    dist = np.full(n_p, np.inf)
    if rr.size and n_p:
        d2 = np.sum((cloud.xy[:, None, :] - scatterers.xy[kk][None, :, :]) ** 2, axis=-1)
        d2[p_radar[:, None] != rr[None, :]] = np.inf
        owner = np.argmin(d2, axis=1)
        dist = np.sqrt(d2[np.arange(n_p), owner])
        nearest = owner.copy()
        owner[dist > gate_m] = -1
    else:
        nearest = np.full(n_p, -1)
    if rr.size:
        rng_m, ang, unit = frame
        r_t, th_t = rng_m[rr, kk], ang[rr, kk]
        v_t = np.einsum("pd,pd->p", unit[rr, kk], scatterers.velocity[kk])
        snr = expected_snr(system, rr, r_t, th_t, scatterers.rcs[kk])
    else:
        r_t = th_t = v_t = snr = np.zeros(0)
    errors = np.full((rr.size, 4), np.nan)
    extra = np.zeros(rr.size, int)
    extra_err: list[np.ndarray] = []
    matched = np.flatnonzero(owner >= 0)
    if matched.size:
        order = matched[np.lexsort((dist[matched], owner[matched]))]  # by pair, nearest first
        pair = owner[order]
        first = np.r_[True, pair[1:] != pair[:-1]]
        err = np.column_stack([cloud.range_m[order] - r_t[pair], _wrap(cloud.angle_rad[order] - th_t[pair]),
                               cloud.points[order, 2] - v_t[pair],
                               np.log(np.maximum(cloud.points[order, 3], 1e-12) / np.sqrt(np.maximum(snr[pair], 1e-300)))])
        errors[pair[first]] = err[first]
        np.add.at(extra, pair[~first], 1)
        extra_err.append(err[~first])
    false = np.flatnonzero(owner < 0)
    fp = np.column_stack([p_radar[false], cloud.range_m[false], cloud.angle_rad[false], cloud.points[false, 2],
                          cloud.points[false, 3]]) if false.size else np.zeros((0, 5))
    link = np.where(dist[false] <= LINK_M, nearest[false], -1) if false.size else np.zeros(0, int)
    offsets = np.full((false.size, 4), np.nan)
    lk = np.flatnonzero(link >= 0)
    if lk.size:
        pair, f = link[lk], false[lk]
        offsets[lk] = np.column_stack([cloud.range_m[f] - r_t[pair], _wrap(cloud.angle_rad[f] - th_t[pair]),
                                       cloud.points[f, 2] - v_t[pair],
                                       np.log(np.maximum(cloud.points[f, 3], 1e-12) / np.sqrt(np.maximum(snr[pair], 1e-300)))])
    linked = np.bincount(link[lk], minlength=rr.size) if lk.size else np.zeros(rr.size, int)
    static = scatterers.is_static[kk].astype(bool) if rr.size else np.zeros(0, bool)
    return ScanRecord(snr_db=10 * np.log10(np.maximum(snr, 1e-30)), static=static, detected=~np.isnan(errors[:, 0]),
                      errors=errors, extra=extra, extra_errors=np.concatenate(extra_err) if extra_err else empty4,
                      false_points=fp, false_xy=cloud.xy[false] if false.size else np.zeros((0, 2)),
                      false_link=link, link_offsets=offsets, linked=linked)


@dataclass(frozen=True)
class FastRadarTable:
    """The calibrated detector of one radar configuration (see the module docstring).

    Attributes:
        key: :func:`table_key` of the configuration.
        pd_edges_db: (B + 1,) SNR bin edges of ``pd``.
        pd: (2, B) detection probability per class (0 moving, 1 static) and SNR bin.
        pd_trials: (2, B) pairs measured per bin.
        extra_rate: (2, B) extra points per detected pair.
        err_edges_db: (E + 1,) SNR bin edges of the error pools.
        err_pool: (M, 4) measured error vectors (:data:`ERROR_COLUMNS`), grouped by class then bin.
        err_start: (2, E + 1) offsets of each (class, bin) group in ``err_pool`` (a sparse bin points at the
            nearest bin with :data:`MIN_POOL` errors).
        err_stop: (2, E) the groups' ends.
        extra_pool: (X, 4) errors of extra points.
        link_rate: (2, B) linked false points per visible pair.
        link_pool: (L, 4) their offsets from the pair (:data:`ERROR_COLUMNS`), class 0 first.
        link_start: (3,) offsets of each class's group in ``link_pool`` (a class without any: the other's).
        false_counts: (S,) free false points of each calibration scan.
        false_pool: (F, 5) free false points (:data:`FALSE_COLUMNS`).
        false_scale: the drawn false-point count's scale (:func:`refine`: a drawn false point that lands within the
            gate of a scatterer is no false point, so the fast radar draws slightly more to measure the same rate).
        link_scale: the linked false points' rate scale (:func:`refine`, the same reason).
        meta: provenance (scenes, seeds, scans, version).
    """

    key: str
    pd_edges_db: np.ndarray
    pd: np.ndarray
    pd_trials: np.ndarray
    extra_rate: np.ndarray
    err_edges_db: np.ndarray
    err_pool: np.ndarray
    err_start: np.ndarray
    err_stop: np.ndarray
    extra_pool: np.ndarray
    link_rate: np.ndarray
    link_pool: np.ndarray
    link_start: np.ndarray
    false_counts: np.ndarray
    false_pool: np.ndarray
    false_scale: float = 1.0
    link_scale: float = 1.0
    meta: dict[str, Any] = field(default_factory=dict)

    def save(self, path: Path) -> None:
        """Write the table as ``.npz`` (float32 pools)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, key=self.key, pd_edges_db=self.pd_edges_db, pd=self.pd, pd_trials=self.pd_trials,
                            extra_rate=self.extra_rate, err_edges_db=self.err_edges_db,
                            err_pool=self.err_pool.astype(np.float32), err_start=self.err_start, err_stop=self.err_stop,
                            extra_pool=self.extra_pool.astype(np.float32), false_counts=self.false_counts,
                            false_pool=self.false_pool.astype(np.float32), false_scale=self.false_scale,
                            link_rate=self.link_rate, link_pool=self.link_pool.astype(np.float32),
                            link_start=self.link_start, link_scale=self.link_scale,
                            meta=json.dumps(self.meta))
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> FastRadarTable:
        """Read a table written by :meth:`save` (``ValueError`` naming the file when it is not one)."""
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: not a fast-radar table ({exc}); recalibrate with "
                             "scripts/calibrate_fast_radar.py") from None
        meta = json.loads(str(arrays.pop("meta")))
        if meta.get("version") != TABLE_VERSION:
            raise ValueError(f"{path}: fast-radar table version {meta.get('version')}, this package reads "
                             f"{TABLE_VERSION}; recalibrate with scripts/calibrate_fast_radar.py")
        arrays["key"] = str(arrays["key"])
        scalars = ("key", "false_scale", "link_scale")
        return cls(**{k: (v.astype(float) if v.dtype == np.float32 else v) for k, v in arrays.items()
                      if k not in scalars}, key=arrays["key"], false_scale=float(arrays["false_scale"]),
                   link_scale=float(arrays["link_scale"]), meta=meta)


class TableBuilder:
    """Accumulates :class:`ScanRecord` s into a :class:`FastRadarTable`."""

    def __init__(self) -> None:
        self.records: list[ScanRecord] = []

    def add(self, record: ScanRecord) -> None:
        """Keep one scan's record."""
        self.records.append(record)

    def build(self, key: str, meta: dict[str, Any], pool_cap: int = 800, seed: int = 0) -> FastRadarTable:
        """The table of the records so far.

        Args:
            key: the configuration's :func:`table_key`.
            meta: provenance to keep in the table.
            pool_cap: at most this many error vectors per (class, bin), drawn without replacement.
            seed: the draw's seed.

        Returns:
            The table.
        """
        if not self.records:
            raise ValueError("no scans recorded: calibrate on at least one scan")
        rng = np.random.default_rng(seed)
        cat = {name: np.concatenate([getattr(r, name) for r in self.records])
               for name in ("snr_db", "static", "detected", "errors", "extra", "extra_errors", "linked")}
        cls_ = cat["static"].astype(int)
        n_pd = PD_EDGES_DB.size - 1
        pbin = np.clip(np.digitize(cat["snr_db"], PD_EDGES_DB) - 1, 0, n_pd - 1)
        trials = np.zeros((2, n_pd))
        hits = np.zeros((2, n_pd))
        extra = np.zeros((2, n_pd))
        np.add.at(trials, (cls_, pbin), 1)
        np.add.at(hits, (cls_, pbin), cat["detected"])
        np.add.at(extra, (cls_, pbin), cat["extra"])
        pd = _fill_rates(hits, trials)
        extra_rate = _fill_rates(extra, np.maximum(hits, 0), default=0.0)
        n_e = ERR_EDGES_DB.size - 1
        ebin = np.clip(np.digitize(cat["snr_db"], ERR_EDGES_DB) - 1, 0, n_e - 1)
        pools, start, stop = [], np.zeros((2, n_e + 1), int), np.zeros((2, n_e), int)
        offset = 0
        groups: dict[tuple[int, int], tuple[int, int]] = {}
        for c in (0, 1):
            for b in range(n_e):
                sel = np.flatnonzero(cat["detected"] & (cls_ == c) & (ebin == b))
                if sel.size > pool_cap:
                    sel = np.sort(rng.choice(sel, pool_cap, replace=False))
                pools.append(cat["errors"][sel])
                groups[(c, b)] = (offset, offset + sel.size)
                offset += sel.size
        for c in (0, 1):
            sizes = np.array([groups[(c, b)][1] - groups[(c, b)][0] for b in range(n_e)])
            for b in range(n_e):
                src = b
                if sizes[b] < MIN_POOL:  # borrow the nearest bin of the class with enough errors, else the other class
                    ok = np.flatnonzero(sizes >= MIN_POOL)
                    if ok.size:
                        src = int(ok[np.argmin(np.abs(ok - b))])
                    elif sizes.max() > 0:
                        src = int(np.argmax(sizes))
                    else:
                        other = np.array([groups[(1 - c, j)][1] - groups[(1 - c, j)][0] for j in range(n_e)])
                        j = int(np.argmax(other))
                        start[c, b], stop[c, b] = groups[(1 - c, j)]
                        continue
                start[c, b], stop[c, b] = groups[(c, src)]
            start[c, n_e] = stop[c, n_e - 1]
        err_pool = np.concatenate(pools) if pools else np.zeros((0, 4))
        if not err_pool.shape[0]:
            raise ValueError("the calibration detected nothing: no error vectors to draw from")
        counts = np.array([int(np.sum(r.false_link < 0)) for r in self.records])
        free = np.concatenate([r.false_points[r.false_link < 0] for r in self.records])
        linked_n = np.zeros((2, n_pd))
        np.add.at(linked_n, (cls_, pbin), cat["linked"])
        link_rate = _fill_rates(linked_n, trials, default=0.0)
        link_cls = np.concatenate([cls_[r_off + r.false_link[r.false_link >= 0]]
                                   for r, r_off in zip(self.records, np.cumsum([0] + [r.snr_db.size for r in
                                                                                     self.records[:-1]]), strict=True)])
        link_off = np.concatenate([r.link_offsets[r.false_link >= 0] for r in self.records])
        order = np.argsort(link_cls, kind="stable")
        link_pool, link_cls = link_off[order], link_cls[order]
        link_start = np.searchsorted(link_cls, [0, 1, 2])
        meta = {**meta, "version": TABLE_VERSION, "scans": len(self.records), "pairs": int(cls_.size),
                "detected": int(cat["detected"].sum()), "free_false_points": int(counts.sum()),
                "linked_false_points": int(link_pool.shape[0])}
        return FastRadarTable(key=key, pd_edges_db=PD_EDGES_DB.copy(), pd=pd, pd_trials=trials, extra_rate=extra_rate,
                              err_edges_db=ERR_EDGES_DB.copy(), err_pool=err_pool, err_start=start, err_stop=stop,
                              extra_pool=cat["extra_errors"], link_rate=link_rate, link_pool=link_pool,
                              link_start=link_start, false_counts=counts, false_pool=free, meta=meta)


def _fill_rates(num: np.ndarray, den: np.ndarray, default: float | None = None) -> np.ndarray:
    """``num / den`` per (class, bin); bins without trials interpolated along SNR (the class's nearest measured
    bins; ``default`` or the other class where a class has none)."""
    out = np.full(num.shape, np.nan)
    ok = den > 0
    out[ok] = num[ok] / den[ok]
    x = np.arange(num.shape[1])
    for c in range(num.shape[0]):
        m = ok[c]
        if m.any():
            out[c] = np.interp(x, x[m], out[c, m])
    for c in range(num.shape[0]):
        if not ok[c].any():
            out[c] = out[1 - c] if ok[1 - c].any() else (default if default is not None else 0.0)
    return out


def load_table(config: Any) -> FastRadarTable:
    """The fast radar's table for ``config``: shipped, else cached; else :class:`MissingCalibrationError` saying how
    to calibrate.

    Args:
        config: the :class:`rhs_env.radar_config.RadarConfig`.

    Returns:
        The table.
    """
    key = table_key(config)
    for path in (shipped_table_path(config), cached_table_path(config)):
        if path.is_file():
            table = FastRadarTable.load(path)
            if table.key != key:
                raise ValueError(f"{path}: table for settings {table.key}, expected {key}; recalibrate with "
                                 "scripts/calibrate_fast_radar.py")
            return table
    raise MissingCalibrationError(
        f"the fast radar has no calibration for these radar settings (key {key}): only the default radar's "
        "ships. Calibrate them once (cached in the user cache) with "
        "`python scripts/calibrate_fast_radar.py --radar '<the radar settings as JSON>'`, or pass "
        "radar_model='fast-calibrate' to calibrate at first use; radar_model='exact' needs none")


def calibration_scenes(seeds: Iterable[int], steps: int, env_kwargs: dict[str, Any] | None = None) -> Iterable[tuple]:
    """Yield ``(seed, step, env)`` along random-action highway episodes (``rhs-highway-v0``'s scene).

    Args:
        seeds: one episode per seed (the actions are drawn from a generator of the same seed).
        steps: at most this many steps per episode (a crash ends it earlier).
        env_kwargs: scene config for :class:`rhs_env.envs.RHSHighwayEnv`.

    Yields:
        The seed, the step index (0 is the reset) and the env, positioned at that step.
    """
    from rhs_env.envs import RHSHighwayEnv

    # the radar reads the scene, not highway-env's observation: the one that costs nothing
    env = RHSHighwayEnv(**{"observation": {"type": "AttributesObservation", "attributes": []}, **(env_kwargs or {})})
    try:
        for seed in seeds:
            env.reset(seed=int(seed))
            act = np.random.default_rng([int(seed), 7])
            yield int(seed), 0, env
            for t in range(1, steps + 1):
                # mostly IDLE (a random driver crashes within seconds), some lane changes and speed changes
                a = int(act.choice(5, p=[0.1, 0.6, 0.1, 0.1, 0.1]))
                _, _, term, trunc, _ = env.step(a)
                if term or trunc:
                    break
                yield int(seed), t, env
    finally:
        env.close()


def measure(config: Any, seeds: Iterable[int], steps: int = 40, gate_m: float = 1.0,
            env_kwargs: dict[str, Any] | None = None,
            progress: bool = False) -> tuple[FastRadarTable, list[tuple[Any, Any]], list[ScanRecord]]:
    """Run the exact radar on highway scenes and build the first table (:func:`refine` corrects it).

    Args:
        config: the :class:`rhs_env.radar_config.RadarConfig` to calibrate.
        seeds: scene seeds (one episode each; keep them disjoint from any fidelity check's).
        steps: steps per episode.
        gate_m: matching gate (:func:`match_scan`).
        env_kwargs: scene config (default: the project's highway).
        progress: print one line per episode.

    Returns:
        The table, the ``(scatterers, occluders)`` of every scan and the exact radar's records on them.
    """
    from rhs_env.radar import RadarSystem
    from rhs_env.scene import ScatterConfig, scene_scatterers

    seeds = list(seeds)
    radar = RadarSystem(config, np.random.default_rng(0))
    scatter = ScatterConfig.make(None)
    builder = TableBuilder()
    scenes = []
    for seed, t, env in calibration_scenes(seeds, steps, env_kwargs):
        if t == 0:
            radar.rng = np.random.default_rng([seed, 11])
            if progress:
                print(f"calibrate: seed {seed} ({len(builder.records)} scans so far)", flush=True)
        sc, occ = scene_scatterers(env, env.unwrapped.vehicle, scatter, config.kernels)
        builder.add(match_scan(radar, radar.scan(sc, occ), sc, occ, gate_m))
        scenes.append((sc, occ))
    meta = {"seeds": [int(seeds[0]), int(seeds[-1])], "episodes": len(seeds), "steps": int(steps),
            "gate_m": float(gate_m), "scene": "rhs-highway-v0 (random meta-actions, mostly IDLE)"}
    return builder.build(table_key(config), meta), scenes, builder.records


def refine(table: FastRadarTable, fast: Any, scenes: list[tuple[Any, Any]], exact: list[ScanRecord],
           gate_m: float = 1.0, iterations: int = 2) -> FastRadarTable:
    """Correct the table so that the fast radar *measures* the exact radar's rates on the calibration scenes.

    The matching that measures ``P_d`` also judges the fast radar's points: a drawn point can land nearer another
    scatterer of the same vehicle than its own (that one then counts it, its own is missed), and a drawn false
    point can land within the gate of a scatterer. Each iteration runs the fast radar on the calibration scenes,
    adds the difference of the measured ``P_d`` per (class, bin) to the table's, and scales the false-point
    count by the ratio of the measured rates.

    Args:
        table: the first table (:func:`measure`).
        fast: a :class:`rhs_env.fast_radar.FastRadarSystem` of the settings (its ``table`` and ``rng`` are set here).
        scenes: ``(scatterers, occluders)`` of every calibration scan.
        exact: the exact radar's records on them.
        gate_m: matching gate.
        iterations: fixed-point iterations.

    Returns:
        The corrected table (``meta["refine"]`` has the remaining differences).
    """
    from dataclasses import replace

    hits_e, trials = _pd_counts(exact, table.pd_edges_db)
    free_e, link_e = _false_counts(exact)
    target = np.where(trials > 0, hits_e / np.maximum(trials, 1), table.pd)
    history = []
    for it in range(iterations + 1):
        fast.table = table
        fast.rng = np.random.default_rng([it, 17])
        recs = [match_scan(fast, fast.scan(sc, occ), sc, occ, gate_m) for sc, occ in scenes]
        hits_f, trials_f = _pd_counts(recs, table.pd_edges_db)
        measured = np.where(trials_f > 0, hits_f / np.maximum(trials_f, 1), table.pd)
        free_f, link_f = _false_counts(recs)
        ok = trials >= 30
        history.append({"max_pd_diff": float(np.max(np.abs(measured - target)[ok])) if ok.any() else 0.0,
                        "free_false_ratio": float(free_f / max(free_e, 1)),
                        "linked_false_ratio": float(link_f / max(link_e, 1))})
        if it == iterations:
            break
        pd = np.clip(table.pd + np.where(ok, target - measured, 0.0), 0.0, 1.0)
        table = replace(table, pd=pd, false_scale=float(table.false_scale * free_e / max(free_f, 1)),
                        link_scale=float(table.link_scale * link_e / max(link_f, 1)))
    return replace(table, meta={**table.meta, "refine": history})


def _false_counts(records: list[ScanRecord]) -> tuple[int, int]:
    """(free, linked) false points of the records."""
    free = sum(int(np.sum(r.false_link < 0)) for r in records)
    return free, sum(int(np.sum(r.false_link >= 0)) for r in records)


def _pd_counts(records: list[ScanRecord], edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(detected, trials) per class and bin of ``edges``."""
    snr = np.concatenate([r.snr_db for r in records])
    cls_ = np.concatenate([r.static for r in records]).astype(int)
    det = np.concatenate([r.detected for r in records])
    b = np.clip(np.digitize(snr, edges) - 1, 0, edges.size - 2)
    hits, trials = np.zeros((2, edges.size - 1)), np.zeros((2, edges.size - 1))
    np.add.at(trials, (cls_, b), 1)
    np.add.at(hits, (cls_, b), det)
    return hits, trials


def pd_of(table: FastRadarTable, snr_db: np.ndarray, static: np.ndarray) -> np.ndarray:
    """``P_d`` of pairs (expected SNR in dB, static flag), linear between the bin centres."""
    centres = 0.5 * (table.pd_edges_db[1:] + table.pd_edges_db[:-1])
    out = np.empty(snr_db.size)
    for c in (0, 1):
        sel = static == bool(c)
        out[sel] = np.interp(snr_db[sel], centres, table.pd[c])
    return out


def extra_rate_of(table: FastRadarTable, snr_db: np.ndarray, static: np.ndarray) -> np.ndarray:
    """Extra points per detected pair, per pair (as :func:`pd_of`)."""
    return _rate_of(table, table.extra_rate, snr_db, static)


def link_rate_of(table: FastRadarTable, snr_db: np.ndarray, static: np.ndarray) -> np.ndarray:
    """Linked false points per visible pair, per pair (as :func:`pd_of`), times the table's ``link_scale``."""
    return table.link_scale * _rate_of(table, table.link_rate, snr_db, static)


def _rate_of(table: FastRadarTable, rate: np.ndarray, snr_db: np.ndarray, static: np.ndarray) -> np.ndarray:
    centres = 0.5 * (table.pd_edges_db[1:] + table.pd_edges_db[:-1])
    out = np.empty(snr_db.size)
    for c in (0, 1):
        sel = static == bool(c)
        out[sel] = np.interp(snr_db[sel], centres, rate[c])
    return out

