"""Safe reading of rl-baselines3-zoo ``policy_kwargs`` expressions (``agents/hyperparams/*.yml``).

rl-baselines3-zoo ``eval``s a ``policy_kwargs`` string in its own module; hyperparameter files are
shared between users, so here the string is parsed, never run: :func:`parse_policy_kwargs` walks its
syntax tree (:mod:`ast`) and accepts only

* literals: numbers (a leading ``-`` / ``+`` too), strings, ``True`` / ``False`` / ``None``;
* lists, tuples, ``{...}`` dicts and ``dict(key=value, ...)`` calls;
* the names of :data:`ALLOWED_NAMES`: torch's activation functions and optimizers
  (``nn.ReLU``, ``th.nn.Tanh``, ``th.optim.Adam``, ...) and the feature extractors the project
  and stable-baselines3 ship, also written the zoo's way,
  ``importlib.import_module('agents.features').PointSetExtractor`` (the module's old path, as the
  hyperparameter files write it; ``agents.policies.features`` is accepted too).

Anything else (attribute walks such as ``().__class__``, other calls, ``lambda``, comprehensions,
f-strings, subscripts, operators, ``:=``) is a ``ValueError`` naming the file and key, raised before
any of it could run.
"""

from __future__ import annotations

import ast
import importlib
from typing import Any

__all__ = ["ALLOWED_NAMES", "MAX_CHARS", "MAX_DEPTH", "parse_policy_kwargs"]

#: the longest expression read (the shipped ones are ~150 characters)
MAX_CHARS = 10_000
#: the deepest nesting of lists / dicts / calls accepted
MAX_DEPTH = 32

_ACTIVATIONS = ("ReLU", "Tanh", "LeakyReLU", "ELU", "SELU", "SiLU", "GELU", "Sigmoid", "Softplus", "Mish",
                "Identity")
_OPTIMIZERS = ("Adam", "AdamW", "SGD", "RMSprop")
#: the project's extractors under both their paths: the hyperparameter files and the shipped records write the old one
#: (``agents.features``, the same module as ``agents.policies.features``)
_EXTRACTORS = {"agents.features": ("PointSetExtractor", "GridExtractor"),
               "agents.policies.features": ("PointSetExtractor", "GridExtractor"),
               "stable_baselines3.common.torch_layers": ("FlattenExtractor", "CombinedExtractor", "NatureCNN")}


def _allowed_names() -> dict[str, tuple[str, str]]:
    names: dict[str, tuple[str, str]] = {}
    for prefix in ("nn", "th.nn", "torch.nn"):
        names.update({f"{prefix}.{a}": ("torch.nn", a) for a in _ACTIVATIONS})
    for prefix in ("th.optim", "torch.optim"):
        names.update({f"{prefix}.{o}": ("torch.optim", o) for o in _OPTIMIZERS})
    for module, classes in _EXTRACTORS.items():
        names.update({f"{module}.{c}": (module, c) for c in classes})
        names.update({c: (module, c) for c in classes})
    return names


#: the names an expression may use -> (module, attribute) of the object each stands for
ALLOWED_NAMES: dict[str, tuple[str, str]] = _allowed_names()


class _Refused(ValueError):
    """A node of the expression that is not allowed (the message says which)."""


def parse_policy_kwargs(text: str, where: str = "policy_kwargs") -> dict[str, Any]:
    """A zoo-style ``policy_kwargs`` expression -> dict, without running any of it.

    Args:
        text: the expression, e.g. ``"dict(net_arch=[64, 64], activation_fn=nn.ReLU)"``.
        where: what to name in errors (``"FILE: ENV_ID.policy_kwargs"``).

    Returns:
        The dict the expression stands for, with the allowed names resolved to their objects.

    Raises:
        ValueError: naming ``where``, for a syntax error, a construct or name that is not allowed
            (see the module docstring), or a value that is not a dict.
    """
    if not isinstance(text, str):
        raise TypeError(f"{where} must be a string or a mapping, got {type(text).__name__}")
    if len(text) > MAX_CHARS:
        raise ValueError(f"{where}: longer than {MAX_CHARS} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"{where}: not a valid expression ({exc.msg}): {text!r}") from None
    except (RecursionError, MemoryError, ValueError):
        raise ValueError(f"{where}: cannot parse {text[:80]!r}...: nested too deeply") from None
    try:
        value = _value(tree.body, 0)
    except _Refused as exc:
        raise ValueError(f"{where}: {exc} (allowed: numbers, strings, lists, dict(...) and names such as "
                         f"nn.ReLU, th.optim.Adam, importlib.import_module('agents.features').PointSetExtractor); "
                         f"got {text!r}") from None
    if not isinstance(value, dict):
        raise ValueError(f"{where} must be a dict, got {type(value).__name__}: {text!r}")  # noqa: TRY004
    return value


def _value(node: ast.AST, depth: int) -> Any:
    """The value of an allowed ``node`` (``_Refused`` otherwise)."""
    if depth > MAX_DEPTH:
        raise _Refused(f"nested more than {MAX_DEPTH} levels")
    if isinstance(node, ast.Constant):
        if node.value is None or type(node.value) in (bool, int, float, str):
            return node.value
        raise _Refused(f"the constant {node.value!r} is not allowed")
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        operand = node.operand
        number = operand.value if isinstance(operand, ast.Constant) else None
        if isinstance(number, (int, float)) and not isinstance(number, bool):
            return -number if isinstance(node.op, ast.USub) else number
        raise _Refused("a sign before anything but a number is not allowed")
    if isinstance(node, (ast.List, ast.Tuple)):
        if any(isinstance(e, ast.Starred) for e in node.elts):
            raise _Refused("'*' unpacking is not allowed")
        items = [_value(e, depth + 1) for e in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict):
        if any(k is None for k in node.keys):
            raise _Refused("'**' unpacking is not allowed")
        return {_key(k, depth): _value(v, depth + 1) for k, v in zip(node.keys, node.values, strict=True)}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict":
        if node.args or any(kw.arg is None for kw in node.keywords):
            raise _Refused("dict(...) with positional or '**' arguments is not allowed (only key=value)")
        return {kw.arg: _value(kw.value, depth + 1) for kw in node.keywords}
    if isinstance(node, (ast.Name, ast.Attribute)):
        return _named(node)
    raise _Refused(f"{_describe(node)} is not allowed")


def _key(node: ast.AST | None, depth: int) -> Any:
    key = _value(node, depth + 1) if node is not None else None
    if not isinstance(key, (str, int, float, bool)) and key is not None:
        raise _Refused("a dict key other than a string or number is not allowed")
    return key


def _dotted(node: ast.AST) -> str | None:
    """``a.b.c`` for a chain of names, ``m.X`` for ``importlib.import_module('m').X``; None for anything else."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value)
        return None if base is None else f"{base}.{node.attr}"
    if (isinstance(node, ast.Call) and _dotted(node.func) == "importlib.import_module" and len(node.args) == 1
            and not node.keywords and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
        return node.args[0].value
    return None


def _named(node: ast.Name | ast.Attribute) -> Any:
    """The object an allowed dotted name stands for (imported from the fixed table, nothing else)."""
    name = _dotted(node)
    if name is None:
        raise _Refused(f"{_describe(node)} is not allowed")
    if name not in ALLOWED_NAMES:
        raise _Refused(f"the name {name!r} is not allowed")
    module, attribute = ALLOWED_NAMES[name]
    return getattr(importlib.import_module(module), attribute)


def _describe(node: ast.AST) -> str:
    kinds = {ast.Lambda: "lambda", ast.NamedExpr: "':='", ast.JoinedStr: "an f-string", ast.Subscript: "indexing",
             ast.Call: "a call other than dict(...) or importlib.import_module('MODULE')", ast.BinOp: "an operator",
             ast.BoolOp: "an operator", ast.Compare: "a comparison", ast.IfExp: "'if ... else'",
             ast.ListComp: "a comprehension", ast.SetComp: "a comprehension", ast.DictComp: "a comprehension",
             ast.GeneratorExp: "a comprehension", ast.Set: "a set", ast.Attribute: "this attribute access",
             ast.Await: "await", ast.Yield: "yield", ast.Starred: "'*' unpacking"}
    for kind, text in kinds.items():
        if isinstance(node, kind):
            return text
    return f"a {type(node).__name__} expression"
