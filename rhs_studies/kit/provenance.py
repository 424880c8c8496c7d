"""Provenance of a study's results (:mod:`rhs_studies.provenance`): what the kit's studies write beside their numbers."""

from __future__ import annotations

from rhs_studies.provenance import (
    FINGERPRINTS,
    ROOT,
    ROUNDING_RTOL,
    STATE_AT_START,
    command_line,
    compute_fingerprint,
    git_state,
    jsonable,
    load_fingerprints,
    numbers,
    package_versions,
    provenance,
    script_name,
    verification,
    write_json,
)

__all__ = ["FINGERPRINTS", "ROOT", "ROUNDING_RTOL", "STATE_AT_START", "command_line", "compute_fingerprint",
           "git_state", "jsonable", "load_fingerprints", "numbers", "package_versions", "provenance", "script_name",
           "verification", "write_json"]
