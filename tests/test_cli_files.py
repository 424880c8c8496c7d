"""The command line's files, flags and interrupts: every fault a user met, one row each, in its own process.

:data:`FAULTS` is the table (``Fault(name, argv, files, fragments, ...)``): each row runs
``python -m rhs_slam.cli ARGV`` in a scratch folder, in a child process with a time limit (a
named pipe, ``/dev/zero`` or a YAML alias bomb hung or filled the memory before), and must
end with exit status 2 and one line on stderr that holds every fragment, no traceback, before
any work: the inputs are unchanged and no result file appears. Beside the table: the neighbours
that must still work (an output through a symlink or over an old result, the shipped YAML files
with their aliases, a merge key overridden), ``--version``, Ctrl-C in ``demo``, ``evaluate`` and
``scenario`` (each in a child that sends itself SIGINT at a chosen moment), the atomic writer, and
seeded cases of the reader rules (a key given twice is refused; aliases are followed up to a node
budget).

Run against the tree before these checks, 39 of the tests here failed: every row of FAULTS but
the directory one (the named pipes and the alias bomb hung to the time limit; the scene, the
scenario and the policy record were overwritten; keys given twice and contradictory flags were
accepted; ``--figure x.txt`` failed with a traceback only after the evaluation), ``--version``, the
five Ctrl-C cases of ``demo`` and ``evaluate`` (tracebacks, no ``partial``), the duplicate-key rule
and the five alias cases past the budget (two of them still walking the document after 10 s).
``/dev/zero`` as a scene read without end (still reading after 10 s under a 4 GB memory limit).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest
import yaml

from rhs_common.input_files import MAX_YAML_ALIASES, MAX_YAML_NODES, InputError, parse_json, read_yaml
from rhs_common.output_files import atomic_output, write_text_atomic

ROOT = Path(__file__).resolve().parents[1]
HW = "rhs-highway-v0"
SCENE = {"targets": [[20.0, 0.0, 5.0]], "antenna": "hologram"}
SCENARIO = {"landmarks": [[10.0, 5.0]], "poses": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], "antenna": "hologram",
            "grid_deg": 5.0, "registration": "odometry", "particles": 5}
#: a ground-truth env of 2 s: an episode in a fraction of a second
FAST_ENV = ["--env", HW, "--env-kwargs", json.dumps({"duration": 2, "vehicles_count": 2, "lanes_count": 2})]
TRAIN_FAST = ["train", "--env", HW, "--timesteps", "64", "--n-envs", "1", "--eval-freq", "0", "--checkpoint-freq",
              "0", "--no-progress", "--out", "run"]
#: nine levels of nine aliases: 9**9 strings once followed (the "billion laughs" of YAML)
ALIAS_BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{n}: &{n} [{', '.join([f'*{p}'] * 9)}]\n" for p, n in zip("abcdefgh", "bcdefghi"))
HP_OK = "rhs-highway-v0:\n  policy: MultiInputPolicy\n"
FIFO, DIR = "<fifo>", "<dir>"  # file contents that make a named pipe / a directory instead


def _doc(d: dict) -> str:
    return json.dumps(d)


@dataclass(frozen=True)
class Fault:
    name: str
    argv: list[str]
    files: dict[str, str] = field(default_factory=dict)  # name -> text, FIFO, DIR, or "link:TARGET" / "hard:TARGET"
    fragments: tuple[str, ...] = ()
    env: dict[str, str] = field(default_factory=dict)
    timeout_s: float = 60.0


SCAN = {"scene.json": _doc(SCENE)}
SCEN = {"sc.json": _doc(SCENARIO)}
FAULTS = [
    # ---- an output onto an input
    Fault("scan --out is the scene", ["scan", "scene.json", "--out", "scene.json"], SCAN, ("--out", "the scene")),
    Fault("scan --out is a symlink to the scene", ["scan", "scene.json", "--out", "link.json"],
          {**SCAN, "link.json": "link:scene.json"}, ("--out", "the scene")),
    Fault("scan --out is a hard link to the scene", ["scan", "scene.json", "--out", "hard.json"],
          {**SCAN, "hard.json": "hard:scene.json"}, ("--out", "the scene")),
    Fault("scenario --out is the scenario", ["scenario", "sc.json", "--out", "./sc.json"], SCEN,
          ("--out", "the scenario")),
    Fault("evaluate --out is the policy's record", ["evaluate", "--policy", "pol.zip", "--out", "pol.json"],
          {"pol.zip": "not a zip", "pol.json": "{}"}, ("--out", "record")),
    Fault("evaluate --out is the policy", ["evaluate", "--policy", "pol.zip", "--out", "pol.zip"],
          {"pol.zip": "not a zip", "pol.json": "{}"}, ("--out", "--policy")),
    # ---- not a regular file, or too large
    Fault("scan scene is a named pipe", ["scan", "fifo.json", "--out", "out.json"], {"fifo.json": FIFO},
          ("fifo.json", "named pipe")),
    Fault("scan --out is a named pipe", ["scan", "scene.json", "--out", "fifo.json"], {**SCAN, "fifo.json": FIFO},
          ("--out", "named pipe")),
    Fault("scenario is a named pipe", ["scenario", "fifo.json", "--out", "out.json"], {"fifo.json": FIFO},
          ("fifo.json", "named pipe")),
    Fault("scenario --out is a named pipe", ["scenario", "sc.json", "--out", "fifo.json"], {**SCEN, "fifo.json": FIFO},
          ("--out", "named pipe")),
    Fault("evaluate --out is a named pipe", ["evaluate", "--policy", "constant:1", *FAST_ENV, "--out", "fifo.json"],
          {"fifo.json": FIFO}, ("--out", "named pipe")),
    Fault("patterns --out is a named pipe", ["patterns", "--grid-deg", "10", "--out", "fifo.npz"], {"fifo.npz": FIFO},
          ("--out", "named pipe")),
    Fault("scan scene is /dev/zero", ["scan", "/dev/zero", "--out", "out.json"], {}, ("/dev/zero", "character device")),
    Fault("scan scene is a directory", ["scan", "d", "--out", "out.json"], {"d": DIR}, ("d", "directory")),
    Fault("scan scene over the size limit", ["scan", "big.json", "--out", "out.json"],
          {"big.json": '{"targets": [[20, 0, 5]], "antenna": "hologram", "seed": 0' + " " * (2 * 2**20) + "}"},
          ("big.json", "RHS_SLAM_MAX_INPUT_MB"), env={"RHS_SLAM_MAX_INPUT_MB": "1"}),
    Fault("size limit variable not a number", ["scan", "scene.json", "--out", "out.json"], SCAN,
          ("RHS_SLAM_MAX_INPUT_MB",), env={"RHS_SLAM_MAX_INPUT_MB": "lots"}),
    # ---- keys given twice, YAML aliases
    Fault("scan duplicate key", ["scan", "scene.json", "--out", "out.json"],
          {"scene.json": '{"targets": [[20, 0, 5]], "antenna": "hologram", "targets": [[30, 0, 5]]}'},
          ("scene.json", "'targets'", "twice")),
    Fault("scenario duplicate key", ["scenario", "sc.json", "--out", "out.json"],
          {"sc.json": _doc(SCENARIO)[:-1] + ', "seed": 1, "seed": 2}'}, ("sc.json", "'seed'", "twice")),
    Fault("evaluate --env-kwargs duplicate key", ["evaluate", "--policy", "constant:1", "--env", HW, "--env-kwargs",
                                                  '{"duration": 2, "duration": 3}', "--out", "out.json"], {},
          ("--env-kwargs", "'duration'", "twice")),
    Fault("evaluate --shield duplicate key", ["evaluate", "--shield", '{"front_time_s": 1, "front_time_s": 2}',
                                              "--out", "out.json"], {}, ("--shield", "'front_time_s'", "twice")),
    Fault("train --hyperparams alias bomb", [*TRAIN_FAST, "--hyperparams", "hp.yml"], {"hp.yml": ALIAS_BOMB + HP_OK},
          ("hp.yml", "alias")),
    Fault("train --hyperparams recursive alias", [*TRAIN_FAST, "--hyperparams", "hp.yml"],
          {"hp.yml": "x: &x [*x]\n" + HP_OK}, ("hp.yml", "alias")),
    Fault("train --hyperparams duplicate key", [*TRAIN_FAST, "--hyperparams", "hp.yml"],
          {"hp.yml": HP_OK + "  gamma: 0.9\n  gamma: 0.99\n"}, ("hp.yml", "'gamma'", "twice", "line 4")),
    Fault("train --hyperparams is a named pipe", [*TRAIN_FAST, "--hyperparams", "hp.yml"], {"hp.yml": FIFO},
          ("hp.yml", "named pipe")),
    # ---- output formats, before the run
    Fault("evaluate --figure x.txt", ["evaluate", "--policy", "constant:1", *FAST_ENV, "--out", "out.json", "--figure",
                                      "x.txt"], {}, ("--figure", "'.txt'", ".png", ".pdf")),
    Fault("evaluate --figure equal to --out", ["evaluate", "--policy", "constant:1", *FAST_ENV, "--out", "out.json",
                                               "--figure", "out.json"], {}, ("--figure", "--out")),
    Fault("evaluate --out x.png (the figure's default)", ["evaluate", "--policy", "constant:1", *FAST_ENV, "--out",
                                                          "x.png"], {}, ("--figure", "--out")),
    # ---- contradictory flags
    Fault("evaluate --shield with --no-shield", ["evaluate", "--shield", "--no-shield", "--out", "out.json"], {},
          ("--shield", "--no-shield")),
    Fault("evaluate --shield with idm (which ignores actions)", ["evaluate", "--policy", "idm:25", "--shield",
                                                                  "--out", "out.json"], {}, ("--shield", "'idm:25'")),
    Fault("evaluate --stochastic with idm", ["evaluate", "--policy", "idm", "--stochastic", "--out", "out.json"], {},
          ("--stochastic", "'idm'")),
    Fault("evaluate --stochastic with headway:5", ["evaluate", "--policy", "headway:5", "--stochastic", "--out",
                                                   "out.json"], {}, ("--stochastic", "'headway:5'")),
]


def _setup(folder: Path, files: dict[str, str]) -> dict[str, bytes]:
    """Write ``files`` into ``folder``; returns the bytes of the regular ones (to check they stay as they were)."""
    kept = {}
    for name, text in files.items():
        path = folder / name
        if text == FIFO:
            os.mkfifo(path)
        elif text == DIR:
            path.mkdir()
        elif text.startswith("link:"):
            path.symlink_to(text[5:])
        elif text.startswith("hard:"):
            os.link(folder / text[5:], path)
        else:
            path.write_text(text)
            kept[name] = text.encode()
    return kept


def _cli(argv: list[str], cwd: Path, timeout_s: float, env: dict[str, str] | None = None,
         code: str = "from rhs_slam.cli import main; raise SystemExit(main())") -> subprocess.CompletedProcess:
    """``rhs-slam ARGV`` in a child process in ``cwd``; a hang fails the test at ``timeout_s``."""
    full_env = {**os.environ, "OMP_NUM_THREADS": "1", "RHS_SLAM_CACHE": str(cwd / ".cache"),
                "PYTHONPATH": str(ROOT), **(env or {})}
    full_env.pop("RHS_SLAM_BUILD_PATTERNS", None)
    try:
        return subprocess.run([sys.executable, "-c", code, *argv], cwd=cwd, env=full_env, capture_output=True,
                              text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        pytest.fail(f"rhs-slam {' '.join(argv)[:120]}: no answer after {timeout_s:g} s (a hang)")


def _no_temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp" in p.name)


@pytest.mark.parametrize("fault", FAULTS, ids=[f.name for f in FAULTS])
def test_a_fault_is_refused_before_any_work(fault, tmp_path):
    kept = _setup(tmp_path, fault.files)
    before = set(os.listdir(tmp_path))
    proc = _cli(fault.argv, tmp_path, fault.timeout_s, fault.env)
    err = proc.stderr.strip()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert proc.returncode == 2, err[-2000:]
    assert len(lines) == 1 and "Traceback" not in err, err[-2000:]
    assert all(f in lines[0] for f in fault.fragments), (fault.fragments, lines[0])
    for name, data in kept.items():  # the inputs as they were, nothing new written
        assert (tmp_path / name).read_bytes() == data, name
    new = set(os.listdir(tmp_path)) - before - {".cache"}  # at most the empty output folder train makes first
    assert all((tmp_path / n).is_dir() and not any((tmp_path / n).iterdir()) for n in new), sorted(new)
    for name, text in fault.files.items():
        if text == FIFO:
            assert (tmp_path / name).is_fifo()


# --------------------------------------------------------------------------- what must still work
def test_scan_writes_through_a_symlink_and_over_an_old_result(tmp_path):
    """An existing result is replaced whole (atomically, no temporary left); a symlinked --out updates its target."""
    _setup(tmp_path, {**SCAN, "real.json": "old", "link.json": "link:real.json", "out.json": "old"})
    for out in ("out.json", "link.json", "new/folder/out.json"):
        proc = _cli(["scan", "scene.json", "--out", out, "--grid-deg", "5"], tmp_path, 120)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert json.loads((tmp_path / out).read_text())["points"]
    assert (tmp_path / "link.json").is_symlink() and json.loads((tmp_path / "real.json").read_text())["points"]
    assert _no_temporaries(tmp_path) == [] and _no_temporaries(tmp_path / "new" / "folder") == []


def test_shipped_hyperparameter_files_still_read():
    """Their anchors and aliases (``&slam`` ... ``*slam``) are well inside the limits."""
    files = sorted((ROOT / "agents" / "hyperparams").glob("*.yml"))
    assert files
    for path in files:
        assert read_yaml(path) == yaml.safe_load(path.read_text()), path.name


def test_a_merge_key_may_be_overridden(tmp_path):
    """``<<: *base`` then one of its keys again is YAML's way to override, not a key given twice."""
    path = tmp_path / "hp.yml"
    path.write_text("base: &b {gamma: 0.9, n_steps: 8}\nrun:\n  <<: *b\n  gamma: 0.99\n")
    assert read_yaml(path)["run"] == {"gamma": 0.99, "n_steps": 8}


def test_version_is_the_installed_package():
    proc = _cli(["--version"], ROOT, 60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"rhs-slam {version('rhs-slam')}"


# --------------------------------------------------------------------------- Ctrl-C
#: run rhs-slam with SIGINT sent to itself at the N-th call of ``module.name`` (from ``RHS_TEST_SIGINT``)
SIGINT_AT = """
import os, signal, sys, importlib
module, name, n = os.environ["RHS_TEST_SIGINT"].split(":")
mod = importlib.import_module(module)
real, calls = getattr(mod, name), [0]
def hooked(*a, **k):
    calls[0] += 1
    if calls[0] == int(n):
        os.kill(os.getpid(), signal.SIGINT)
    return real(*a, **k)
setattr(mod, name, hooked)
from rhs_slam.cli import main
raise SystemExit(main())
"""


def _interrupted(argv: list[str], cwd: Path, at: str) -> tuple[subprocess.CompletedProcess, str]:
    proc = _cli(argv, cwd, 240, {"RHS_TEST_SIGINT": at}, code=SIGINT_AT)
    err = proc.stderr.strip()
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-2000:]
    last = err.splitlines()[-1]
    assert "interrupted" in last, last
    return proc, last


DEMO = ["demo", "--policy", "constant:1", *FAST_ENV, "--out", "d"]


def test_demo_interrupted_during_the_episode_writes_a_partial_record(tmp_path):
    """SIGINT at the third step: ``demo.json`` holds the steps driven and ``"partial": true``; the figure of an
    earlier run in the folder is left as it was."""
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "trajectory_map.png").write_bytes(b"an earlier run's figure")
    _, last = _interrupted(DEMO, tmp_path, "agents.evaluate:env_action:3")
    record = json.loads((tmp_path / "d" / "demo.json").read_text())
    assert record["partial"] is True and record["steps"] == 2 and record["interrupted"] == "SIGINT", record
    assert "demo.json" in last and "partial" in last
    assert (tmp_path / "d" / "trajectory_map.png").read_bytes() == b"an earlier run's figure"
    assert _no_temporaries(tmp_path / "d") == []


def test_demo_interrupted_while_writing_the_figure(tmp_path):
    """The episode is done: the record has its results and is partial; no half figure, no temporary file."""
    _interrupted(DEMO, tmp_path, "agents.demo:plot_summary:1")
    record = json.loads((tmp_path / "d" / "demo.json").read_text())
    assert record["partial"] is True and "return" in record and "figure" not in record, record
    assert not (tmp_path / "d" / "trajectory_map.png").exists() and _no_temporaries(tmp_path / "d") == []


def test_demo_interrupted_before_the_episode_writes_nothing(tmp_path):
    _, last = _interrupted(DEMO, tmp_path, "agents.demo:load_policy:1")
    assert last == "rhs-slam demo: interrupted (Ctrl-C); stopped"
    assert not (tmp_path / "d" / "demo.json").exists()


EVALUATE = ["evaluate", "--policy", "constant:1", *FAST_ENV, "--episodes", "3", "--out", "ev.json", "--no-progress"]


def test_evaluate_interrupted_in_an_episode_writes_the_finished_ones_as_partial(tmp_path):
    _, last = _interrupted(EVALUATE, tmp_path, "agents.evaluate:run_episode:2")
    record = json.loads((tmp_path / "ev.json").read_text())
    assert record["partial"] is True and record["episodes"] == 1 and record["interrupted"] == "SIGINT"
    assert "partial" in last and (tmp_path / "ev.png").exists() and _no_temporaries(tmp_path) == []


def test_evaluate_interrupted_while_writing_leaves_no_record(tmp_path):
    """Past the episodes the signal stops the writing: no JSON that claims a finished run, no temporary file."""
    (tmp_path / "ev.json").write_text("an earlier run")
    _interrupted(EVALUATE, tmp_path, "agents.evaluate:plot_summary:1")
    assert (tmp_path / "ev.json").read_text() == "an earlier run"
    assert not (tmp_path / "ev.png").exists() and _no_temporaries(tmp_path) == []


def test_scenario_interrupted_keeps_the_earlier_result(tmp_path):
    """Any other command: one line, exit 130, and the result file of an earlier run is left whole."""
    _setup(tmp_path, {**SCEN, "out.json": "an earlier run"})
    _, last = _interrupted(["scenario", "sc.json", "--out", "out.json", "--no-progress"], tmp_path,
                           "slam.core.scenario:run_scenario:1")
    assert last == "rhs-slam scenario: interrupted (Ctrl-C); stopped"
    assert (tmp_path / "out.json").read_text() == "an earlier run" and _no_temporaries(tmp_path) == []


# --------------------------------------------------------------------------- the writer, and the rules
def test_atomic_output_leaves_the_old_file_on_failure(tmp_path):
    target = tmp_path / "r.json"
    target.write_text("old")
    with pytest.raises(KeyboardInterrupt), atomic_output(target) as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert target.read_text() == "old" and _no_temporaries(tmp_path) == []
    write_text_atomic(target, "new")
    assert target.read_text() == "new" and _no_temporaries(tmp_path) == []


def _random_doc(rng: np.random.Generator) -> dict:
    """A small JSON object: keys of printable and non-ASCII characters, scalar values."""
    alphabet = list("abcxyz_-0 ") + ["é", "ß", "中", "\\", '"', "\n"]
    values = [0, -3, 2.5, True, False, None, "", "v", "ü"]
    return {"".join(rng.choice(alphabet, size=int(rng.integers(0, 5)))): values[rng.integers(len(values))]
            for _ in range(int(rng.integers(1, 7)))}


def test_a_json_key_given_twice_is_refused_by_name():
    """Seeded: any object reads as it was written; the same text with one key repeated is refused naming it."""
    rng = np.random.default_rng(59)
    for _ in range(200):
        doc = _random_doc(rng)
        assert parse_json(json.dumps(doc), "doc") == doc
        key = sorted(doc)[rng.integers(len(doc))]
        pairs = list(doc.items())
        pairs.insert(int(rng.integers(len(pairs) + 1)), (key, int(rng.integers(100))))
        text = "{" + ", ".join(f"{json.dumps(k)}: {json.dumps(v)}" for k, v in pairs) + "}"
        with pytest.raises(InputError, match="twice") as exc:
            parse_json(text, "doc")
        assert repr(key) in str(exc.value)


#: read a YAML file in a child process: its document as JSON, or ``refused: <message>``
READ_YAML = """
import json, sys
from rhs_common.input_files import InputError, read_yaml
try:
    print(json.dumps(read_yaml(sys.argv[1])))
except InputError as exc:
    print("refused: " + str(exc))
"""


@pytest.mark.parametrize("fanout, depth", [(f, d) for f in (1, 2, 3, 5, 9, 12) for d in (1, 2, 4, 6, 8)])
def test_yaml_aliases_are_followed_up_to_the_node_budget(fanout, depth, tmp_path):
    """``depth`` levels, each a list of ``fanout`` aliases of the level below: read as YAML reads it while the
    expanded document has at most MAX_YAML_NODES nodes and MAX_YAML_ALIASES aliases, refused naming the
    aliases beyond (in a child with a time limit: 12 ** 8 strings took hours to walk)."""
    text = f"l0: &l0 [{', '.join(['x'] * fanout)}]\n" + "".join(
        f"l{k}: &l{k} [{', '.join([f'*l{k - 1}'] * fanout)}]\n" for k in range(1, depth))
    # level k expands to 1 + fanout * size(k - 1) nodes; the document: its mapping, the keys and every level
    sizes = [1 + fanout]
    for _ in range(1, depth):
        sizes.append(1 + fanout * sizes[-1])
    nodes = 1 + depth + sum(sizes)
    path = tmp_path / "a.yml"
    path.write_text(text)
    try:
        out = subprocess.run([sys.executable, "-c", READ_YAML, str(path)], capture_output=True, text=True,
                             timeout=30, env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True).stdout
    except subprocess.TimeoutExpired:
        pytest.fail(f"read_yaml of {fanout} aliases x {depth} levels: no answer after 30 s")
    if nodes <= MAX_YAML_NODES and fanout * (depth - 1) <= MAX_YAML_ALIASES:
        assert json.loads(out) == yaml.safe_load(text)
    else:
        assert out.startswith("refused: ") and "alias" in out, out[:300]
