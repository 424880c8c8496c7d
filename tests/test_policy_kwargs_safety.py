"""``policy_kwargs`` in a hyperparameter file is parsed, never run: the known ``eval`` escapes are refused
with a ``ValueError`` naming the file and key, and none of their code runs."""

from __future__ import annotations

import pytest

from agents.algos.hyperparams import load_hyperparams
from agents.algos.policy_kwargs import parse_policy_kwargs

SENTINEL = "rhs_slam_policy_kwargs_ran"


def escapes(sentinel: str) -> list[str]:
    """Expressions that, ``eval``ed even without builtins, would create ``sentinel`` (a file path)."""
    touch = f"open({sentinel!r}, 'w')"
    sys_call = f"'touch {sentinel}'"
    return [
        # the attribute walk to every loaded class, then to os.system through a class's globals
        "[c for c in ().__class__.__bases__[0].__subclasses__() if c.__name__ == 'catch_warnings'][0]()"
        f"._module.__builtins__['__import__']('os').system({sys_call})",
        "().__class__.__bases__[0].__subclasses__()",
        f"dict(a=importlib.import_module('os').system({sys_call}))",
        f"importlib.import_module('builtins').open({sentinel!r}, 'w')",
        f"dict(net_arch=[64], x=__import__('os').system({sys_call}))",
        f"dict(activation_fn=(lambda: {touch}))",
        f"(lambda: {touch})()",
        f"dict(x=[{touch} for _ in [0]])",
        f"dict(x={{k: {touch} for k in [0]}})",
        f"dict(x=(y := {touch}))",
        f"dict(x=f'{{{touch}}}')",
        f"dict(x=th.nn.ReLU.__init__.__globals__['sys'].modules['os'].system({sys_call}))",
        "dict(x=nn.ReLU.__class__)",
        f"dict(x=th.load({sentinel!r}))",
        f"dict(**{{'a': {touch}}})",
        f"dict(x=[*[{touch}]])",
        "dict(x=9 ** 9 ** 9)",
        "dict(x=th.__builtins__)",
        f"{{'a': 1}}['a'] and {touch}",
        f"dict(x={touch} if True else 0)",
        f"dict(x=getattr(th, 'load')({sentinel!r}))",
        "dict(x=b'bytes')",
    ]


def test_the_shipped_form_parses_to_the_classes():
    from torch import nn

    from agents.policies.features import PointSetExtractor

    got = parse_policy_kwargs("dict(features_extractor_class=importlib.import_module('agents.features')"
                              ".PointSetExtractor, features_extractor_kwargs=dict(point_dim=64, box_dim=32), "
                              "net_arch=dict(pi=[64, 64], vf=[-1, +2]), activation_fn=th.nn.Tanh, ortho_init=False, "
                              "optimizer_kwargs={'eps': 1e-5}, act=nn.ReLU, shape=(1, 2), none=None)")
    assert got == {"features_extractor_class": PointSetExtractor,
                   "features_extractor_kwargs": {"point_dim": 64, "box_dim": 32},
                   "net_arch": {"pi": [64, 64], "vf": [-1, 2]}, "activation_fn": nn.Tanh, "ortho_init": False,
                   "optimizer_kwargs": {"eps": 1e-5}, "act": nn.ReLU, "shape": (1, 2), "none": None}


@pytest.mark.parametrize("index", range(len(escapes("x"))))
def test_an_escape_is_refused_and_runs_nothing(tmp_path, monkeypatch, index):
    monkeypatch.chdir(tmp_path)
    sentinel = tmp_path / SENTINEL
    text = escapes(str(sentinel))[index]
    with pytest.raises(ValueError, match="where.yml: key.policy_kwargs") as err:
        parse_policy_kwargs(text, "where.yml: key.policy_kwargs")
    assert "not allowed" in str(err.value) or "not a valid expression" in str(err.value)
    assert not sentinel.exists()


def test_the_escapes_would_run_under_eval(tmp_path):
    """The check above can fail: ``eval`` with no builtins (the former parser) runs the first escape."""
    import importlib

    import torch
    from torch import nn

    sentinel = tmp_path / SENTINEL
    eval(escapes(str(sentinel))[0], {"__builtins__": {}}, {"dict": dict, "importlib": importlib, "nn": nn, "th": torch})
    assert sentinel.exists()


def test_a_hyperparameter_file_with_an_escape_is_refused_naming_file_and_key(tmp_path):
    sentinel = tmp_path / SENTINEL
    hp = tmp_path / "shared.yml"
    payload = escapes(str(sentinel))[0].replace('"', '\\"')
    hp.write_text(f'rhs-highway-v0:\n  policy: MlpPolicy\n  policy_kwargs: "{payload}"\n')
    with pytest.raises(ValueError, match=r"shared\.yml: rhs-highway-v0\.policy_kwargs: .*not allowed"):
        load_hyperparams("ppo", "rhs-highway-v0", hp)
    assert not sentinel.exists()


def test_train_cli_refuses_it_in_one_line(tmp_path, capsys):
    from rhs_slam.cli import main

    sentinel = tmp_path / SENTINEL
    hp = tmp_path / "shared.yml"
    hp.write_text(f"rhs-highway-v0:\n  policy: MlpPolicy\n  policy_kwargs: \"dict(x=__import__('os').system('touch {sentinel}'))\"\n")
    code = main(["train", "--env", "rhs-highway-v0", "--hyperparams", str(hp), "--out", str(tmp_path / "run"),
                 "--timesteps", "8", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "policy_kwargs" in err and "shared.yml" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not sentinel.exists() and not list(tmp_path.glob("run/*"))


@pytest.mark.parametrize("text", ["dict(net_arch=[64]", "[1, 2]", "dict(a=" * 200 + ")" * 200, "x" * 20_000])
def test_a_malformed_or_huge_expression_is_a_value_error(text):
    with pytest.raises(ValueError, match="policy_kwargs"):
        parse_policy_kwargs(text)
