"""The study contract: options as a frozen dataclass, one runner that parses them, runs, writes and prints.

A study is a :class:`Study`: its name (the results' file stem), its launcher (the ``scripts/NAME.py`` its results
record as their command), a frozen options dataclass whose fields are the command-line options (:func:`option`
gives a field its help text; :func:`parser_for` turns the fields into flags: ``validation_seed`` ->
``--validation-seed``), ``run`` (options -> the result dict), ``markdown`` (result -> the page) and ``fingerprint``.
:func:`run_study` parses the options (a ``ValueError`` from the dataclass or from ``check`` becomes a usage error
naming the flag), runs, writes ``OUT_DIR/NAME.json`` with provenance (:func:`rhs_studies.kit.provenance.write_json`)
and ``OUT_DIR/NAME.md``, and prints the page.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rhs_studies.kit.provenance import write_json


def option(default: Any, help: str = "", **argparse_kwargs: Any) -> Any:
    """A field of an options dataclass with its ``--help`` text (and any extra :meth:`add_argument` keywords,
    e.g. ``choices``).

    Args:
        default: the default value (a tuple for a list option).
        help: the flag's help text.
        **argparse_kwargs: passed to :meth:`argparse.ArgumentParser.add_argument`.

    Returns:
        A :func:`dataclasses.field`.
    """
    return dataclasses.field(default=default, metadata={"help": help, **argparse_kwargs})


def flag_name(field: str) -> str:
    """``validation_seed`` -> ``--validation-seed``."""
    return "--" + field.replace("_", "-")


def parser_for(options_type: type, description: str | None = None) -> argparse.ArgumentParser:
    """An argparse parser with one flag per field of the frozen dataclass ``options_type``.

    Fields of type ``bool`` become ``store_true`` flags, ``tuple[X, ...]`` ``nargs="+"`` lists of X, ``int``,
    ``float``, ``str`` and ``Path`` typed values; the default is the field's.

    Args:
        options_type: a dataclass type.
        description: the parser's description (the study module's docstring).

    Returns:
        The parser.
    """
    ap = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    hints = typing.get_type_hints(options_type)
    for f in dataclasses.fields(options_type):
        kind, extra = hints[f.name], dict(f.metadata)
        name = flag_name(f.name)
        if kind is bool:
            ap.add_argument(name, action="store_true", **extra)
        elif typing.get_origin(kind) is tuple:
            ap.add_argument(name, nargs="+", type=typing.get_args(kind)[0], default=list(f.default), **extra)  # type: ignore[arg-type]
        else:
            ap.add_argument(name, type=kind, default=f.default, **extra)
    return ap


def parse_options(options_type: type, argv: list[str] | None, description: str | None = None,
                  parser: argparse.ArgumentParser | None = None) -> Any:
    """The options of ``argv``: an ``options_type`` built from :func:`parser_for`'s flags (lists as tuples); a
    ``ValueError`` of the dataclass's checks exits with a usage error (status 2) naming it."""
    ap = parser or parser_for(options_type, description)
    args = vars(ap.parse_args(argv))
    hints = typing.get_type_hints(options_type)
    values = {k: tuple(v) if typing.get_origin(hints[k]) is tuple else v for k, v in args.items()}
    try:
        return options_type(**values)
    except ValueError as err:
        ap.error(str(err))


@dataclasses.dataclass(frozen=True)
class Study:
    """What a study is to the runner (:func:`run_study`)."""

    #: the results' file stem: ``OUT_DIR/NAME.json`` and ``.md`` ("": the options' ``result_name``)
    name: str
    #: the launcher whose command the results record (``scripts/NAME.py``) and the fingerprint's key
    launcher: str
    #: a frozen dataclass with an ``out_dir`` field: the options
    options: type
    #: options -> the result (without provenance)
    run: Callable[[Any], dict[str, Any]]
    #: result -> the Markdown page
    markdown: Callable[[dict[str, Any]], str]
    #: the small-config fingerprint (:mod:`rhs_studies.kit.provenance`), or None
    fingerprint: Callable[[], list[float]] | None = None
    #: the ``--help`` text
    description: str | None = None
    #: checks of the options against the files (zips present, seeds fresh): ``ValueError`` -> a usage error
    check: Callable[[Any], None] | None = None


def run_study(study: Study, argv: list[str] | None = None) -> int:
    """Parse ``argv`` into ``study.options``, check them, run, write ``NAME.json`` (with provenance) and ``NAME.md``
    into the options' ``out_dir``, print the page.

    Args:
        study: the study.
        argv: the command-line arguments (None: the process's).

    Returns:
        The exit status (0).
    """
    ap = parser_for(study.options, study.description)
    opts = parse_options(study.options, argv, parser=ap)
    if study.check is not None:
        try:
            study.check(opts)
        except ValueError as err:
            ap.error(str(err))
    started = time.time()
    result = study.run(opts)
    out, name = Path(opts.out_dir), study.name or opts.result_name
    write_json(out / f"{name}.json", result, study.launcher, opts, started, study.fingerprint, argv)
    text = study.markdown(result)
    (out / f"{name}.md").write_text(text)
    print(text)
    return 0


__all__ = ["Study", "flag_name", "option", "parse_options", "parser_for", "run_study"]
