"""Compiled kernels of the radar's processing chain (numba), each beside the stage it accelerates.

Each kernel computes what a numpy function of :mod:`rhs_env.detection` / :mod:`rhs_env.point_cloud` /
:mod:`rhs_env.radar` / :mod:`rhs_env.scene` computes, with its variable names and in the same floating-point order
where the numpy code fixes one (comparisons of float32 statistics stay float32), so the compiled path reproduces the
numpy reference to round-off. A few sums run in another order where that is much faster: the footprint statistic
(:func:`footprint_statistic`: each footprint's 2-4 slots instead of a dense 0 / 1 product, within 1-2 float32 ulp),
the least squares' ``A^H A`` and ``A^H y`` (:func:`lstsq`, :func:`bin_amplitudes`: vectorised sums, ~1e-15
relative), the narrow Doppler searches' DTFT (float32 sums of the complex64 values, the reference's own precision)
and each radar's tone product (:func:`add_tone_products`: scipy's BLAS adds it into the spectrum, numpy's BLAS forms
it in the reference: float32 round-off); the equivalence tests (same detections and point count, positions within
1 mm, Doppler within 1 cm/s) and the results' fingerprints hold. The numpy path stays selectable:
``RadarConfig(kernels="numpy")`` (``gym.make(..., radar={"kernels": "numpy"})``).

One module per stage, named after the numpy code it accelerates:

===========================================  ===========================================================
:mod:`rhs_env.kernels.detection`             the footprint statistic and the CFAR detector
                                             (:class:`rhs_env.detection.FootprintDetector`)
:mod:`rhs_env.kernels.atoms`                 the dictionary's atoms from Taylor tables, Newton steps
                                             (:class:`rhs_env.point_cloud.AngleDictionary`)
:mod:`rhs_env.kernels.synthesis`             the receiver noise and the tone spectra
                                             (:meth:`rhs_env.radar.RadarSystem.synthesize_spectrum`)
:mod:`rhs_env.kernels.omp_stages`            the Doppler OMP's stages, one call each (:mod:`rhs_env.point_cloud`)
:mod:`rhs_env.kernels.omp`                   the whole Doppler OMP in one call (:func:`omp_doppler`)
:mod:`rhs_env.kernels.geometry`              the vehicles' faces and the line of sight
                                             (:mod:`rhs_env.scene`, :mod:`rhs_env.scatterers`)
:mod:`rhs_env.kernels.points`                the targets' range offsets and points
                                             (:class:`rhs_env.radar.RadarSystem`)
===========================================  ===========================================================

Every kernel is importable from this package (``from rhs_env.kernels import omp_doppler``), the name the numpy
code, the tests and :mod:`slam.gym.precompile` use (and, through :func:`__getattr__`, the private stages the
equivalence tests call directly).

Why compiled. The stages work on arrays of 30-300 rows: the numpy reference pays thousands of interpreter-level
calls per scan, several times the arithmetic. The noise generator's transcendental functions stay in numpy (SIMD
there; numba's wheels have no SVML).

Costs of the dependency (numba 0.68.1 / llvmlite 0.50): installed size numba 33 MB + llvmlite 180 MB (llvmlite
carries a static LLVM); every numba release caps numpy (0.68.1: numpy < 2.6; pyproject asks numba >= 0.60, pip
picks the one matching numpy); the first compile of every kernel, once per machine, ~25-40 s (the one-call OMP the
largest part; a background process compiles it, :mod:`slam.gym.precompile`), then a new process loads them from the
cache (:mod:`rhs_common.jit`) in ~2 s. The measurements behind these figures, and how each change of the kernels'
layout moved them, are on the speed page's history (``docs/results/speed.md``).
"""

from __future__ import annotations

from typing import Any

from rhs_env.kernels import atoms, detection, geometry, omp, omp_stages, points, synthesis
from rhs_env.kernels.atoms import (
    PRODUCT_ORDER,
    PRODUCT_SERIES_BOUND,
    TABLE_WORK_MAX,
    TAYLOR_ORDER,
    newton_refine,
    taylor_atoms,
    taylor_tables,
)
from rhs_env.kernels.detection import footprint_detections, footprint_statistic
from rhs_env.kernels.geometry import face_scatterers, line_of_sight
from rhs_env.kernels.omp import omp_doppler, omp_doppler_tiered, warm_refinement
from rhs_env.kernels.omp_stages import (
    RAMP,
    angle_information,
    atom_norms,
    bin_amplitudes,
    doppler_dtft_refine,
    gather_bins,
    joint_refine,
    joint_rho,
    lstsq,
    phasors,
    slot_projection,
    slot_sums,
)
from rhs_env.kernels.points import assemble_points, range_offsets
from rhs_env.kernels.synthesis import add_tone_products, noise_samples, noise_uniforms, tone_operands, tone_spectra

__all__ = [
    "PRODUCT_ORDER", "PRODUCT_SERIES_BOUND", "RAMP", "TABLE_WORK_MAX", "TAYLOR_ORDER", "add_tone_products",
    "angle_information", "assemble_points", "atom_norms", "bin_amplitudes", "doppler_dtft_refine", "face_scatterers",
    "footprint_detections", "footprint_statistic", "gather_bins", "joint_refine", "joint_rho", "line_of_sight", "lstsq",
    "newton_refine", "noise_samples", "noise_uniforms", "omp_doppler", "omp_doppler_tiered", "phasors", "range_offsets",
    "slot_projection", "slot_sums", "taylor_atoms", "taylor_tables", "tone_operands", "tone_spectra", "warm_refinement",
]

_STAGES = (detection, atoms, synthesis, omp_stages, omp, geometry, points)


def __getattr__(name: str) -> Any:
    """Any other name of a stage module (the private stages the equivalence tests call: ``_cfar_pass``, ``_ramp``,
    ``_new_atoms``, ...), looked up in the stage modules, so they keep the names they had in one module."""
    for module in _STAGES:
        if name in vars(module):
            return vars(module)[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
