"""One flag per ``PipelineParams`` field on every command line (issue 17, point 5).

Walks every field of :class:`hdrcore.pipeline.PipelineParams` and every parser that can expose
one (``hdrcore merge``, ``align``, ``ratios``, ``response``, ``batch`` and ``hdrview``): a field
is either on the command line under its one flag (``hdrcore.cli._params.FLAGS``) with the
field's own default, or listed in ``NOT_ON_COMMAND_LINE`` with a reason. A field added with a
different flag name, a different default, or not classified at all fails here.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import pytest

from hdrcore.cli import build_parser, main
from hdrcore.cli._params import (
    DEFAULTS,
    DEPRECATED,
    DESTS,
    FLAGS,
    NOT_ON_COMMAND_LINE,
    params_from_args,
)
from hdrcore.pipeline import PipelineParams

FIELDS = [f.name for f in dataclasses.fields(PipelineParams)]
#: the commands that run the pipeline, and which fields they build PipelineParams from
COMMAND_FIELDS = {
    "merge": "hdrcore.cli.merge:MERGE_FIELDS",
    "align": "hdrcore.cli.align:ALIGN_FIELDS",
    "ratios": "hdrcore.cli.ratios:RATIOS_FIELDS",
}


#: a flag with a field's name that means something else, and why it is left so
CLASHES = {
    ("batch", "--workers"): "worker processes of the batch (each merge keeps the default "
    "threads); hdrcore/cli/batch.py is another engineer's file",
}


def _fields_of(command: str) -> tuple[str, ...]:
    import importlib

    module, name = COMMAND_FIELDS[command].split(":")
    return getattr(importlib.import_module(module), name)


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _all_parsers() -> dict[str, argparse.ArgumentParser]:
    from hdrview.app import build_parser as hdrview_parser

    return {**_subparsers(), "hdrview": hdrview_parser()}


def _visible(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The parser's options, deprecated aliases (hidden from --help) left out."""
    return [a for a in parser._actions if a.option_strings and a.help != argparse.SUPPRESS]


def test_every_field_is_on_the_command_line_or_says_why_not() -> None:
    for field in FIELDS:
        assert (field in FLAGS) != (field in NOT_ON_COMMAND_LINE), (
            f"PipelineParams.{field}: give it a flag in hdrcore/cli/_params.py FLAGS, or say "
            f"in NOT_ON_COMMAND_LINE why no command offers it"
        )
    assert set(FLAGS) <= set(FIELDS) and set(NOT_ON_COMMAND_LINE) <= set(FIELDS)
    for field, reason in NOT_ON_COMMAND_LINE.items():
        assert len(reason) > 20, field


@pytest.mark.parametrize("prog", ["merge", "align", "ratios", "response", "batch", "hdrview"])
def test_each_command_uses_the_fields_flag_and_default(prog: str) -> None:
    parser = _all_parsers()[prog]
    dest_field = {DESTS[f]: f for f in FLAGS}
    flag_field = {flag: f for f, flag in FLAGS.items()}
    dashed = {"--" + f.replace("_", "-"): f for f in FIELDS}
    seen = set()
    for action in _visible(parser):
        field = dest_field.get(action.dest)
        for opt in action.option_strings:
            # a field's flag, or a flag spelled like a field, is that field and nothing else
            # (but --times FILE, the exposure-times list: the field's flag is --times-source)
            owner = flag_field.get(opt, dashed.get(opt) if opt != "--times" else None)
            if owner is not None and (prog, opt) not in CLASHES:
                assert field == owner, f"{prog} {opt} sets {action.dest!r}, not {owner!r}"
        if field is None or (prog, FLAGS[field]) in CLASHES:
            continue
        seen.add(field)
        switch = isinstance(action, argparse.BooleanOptionalAction)
        names = [FLAGS[field], "--no-" + FLAGS[field][2:]] if switch else [FLAGS[field]]
        assert action.option_strings == names, (
            f"{prog}: PipelineParams.{field} is {action.option_strings}, elsewhere {FLAGS[field]}"
        )
        assert action.default == DEFAULTS[field], (
            f"{prog} {FLAGS[field]}: default {action.default!r}, PipelineParams.{field} "
            f"{DEFAULTS[field]!r}"
        )
    if prog in COMMAND_FIELDS:
        assert seen == set(_fields_of(prog))
    if prog in ("merge", "batch"):  # the merge offers every field the command line has
        assert seen == set(FLAGS) - ({"workers"} if prog == "batch" else set())
    if prog in ("response", "hdrview"):
        assert "workers" in seen


@pytest.mark.parametrize("command", sorted(COMMAND_FIELDS))
def test_no_flag_given_is_the_librarys_default(command: str, tmp_path: Path) -> None:
    """Parsed without options, a command's parameters are ``PipelineParams()``'s."""
    extra = ["-o", str(tmp_path / "o.exr")] if command == "merge" else []
    args = build_parser().parse_args([command, "frame.png", *extra])
    params = params_from_args(args, _fields_of(command))
    assert params == PipelineParams()


@pytest.mark.parametrize("command", sorted(COMMAND_FIELDS))
def test_each_flag_reaches_its_field(command: str, tmp_path: Path) -> None:
    values = {
        "saturation": ("250", 250.0),
        "noise_floor": ("3", 3.0),
        "threshold": ("0.2", 0.2),
        "align": ("homography", "homography"),
        "local": ("off", "off"),
        "reference": ("1", 1),
        "response": ("srgb", "srgb"),
        "times": ("exif", "exif"),
        "exposure_method": ("Cerman 2006", "Cerman 2006"),
        "registration_method": ("Cerman 2006", "Cerman 2006"),
        "tonemap": ("linear", "linear"),
        "tonemap_exposure": ("1.5", 1.5),
        "preview_max_side": ("0", None),
        "exclude_colour": ("0,0,255", (0, 0, 255)),
        "ratio_fallback_stops": ("0.5", 0.5),
        "registration_max_pixels": ("2e6", 2000000),
        "refine_ratios": ("none", "none"),
        "noise_sigma": ("1.5", 1.5),
        "workers": ("-1", -1),
    }
    switches = {
        "deghost": ("--deghost", True),
        "colour_anchor": ("--no-colour-anchor", False),
        "white_balance": ("--no-white-balance", False),
    }
    assert set(values) | set(switches) == set(FLAGS)
    extra = ["-o", str(tmp_path / "o.exr")] if command == "merge" else []
    for field in _fields_of(command):
        if field in switches:
            argv, expected = [switches[field][0]], switches[field][1]
        else:
            argv, expected = [FLAGS[field], values[field][0]], values[field][1]
        args = build_parser().parse_args([command, "frame.png", *extra, *argv])
        params = params_from_args(args, _fields_of(command))
        assert getattr(params, field) == expected, (command, field)
        assert params.replace(**{field: DEFAULTS[field]}) == PipelineParams(), (command, field)


OLD = [  # (command, old flags, field, value expected)
    ("merge", ["--exposure", "1.5"], "tonemap_exposure", 1.5),
    ("merge", ["--preview-size", "0"], "preview_max_side", None),
    ("align", ["--model", "shift"], "align", "shift"),
    ("align", ["--method", "Cerman 2006"], "registration_method", "Cerman 2006"),
    ("align", ["--ratios", "exif"], "times", "exif"),
    ("align", ["--ratios", "histogram"], "times", "estimated"),
    ("ratios", ["--method", "Cerman 2006"], "exposure_method", "Cerman 2006"),
    ("ratios", ["--mask-colour", "0,0,255"], "exclude_colour", (0, 0, 255)),
]


@pytest.mark.parametrize(("command", "argv", "field", "expected"), OLD)
def test_old_names_still_work_and_say_so(command, argv, field, expected, tmp_path, capsys):
    assert argv[0] in DEPRECATED[command]
    extra = ["-o", str(tmp_path / "o.exr")] if command == "merge" else []
    args = build_parser().parse_args([command, "frame.png", *extra, *argv])
    assert getattr(params_from_args(args, _fields_of(command)), field) == expected
    err = capsys.readouterr().err
    assert f"{argv[0]} is deprecated" in err and f"use {FLAGS[field]}" in err
    assert err.startswith("hdrcore: warning: ") and err.count("\n") == 1
    # the new name says nothing
    build_parser().parse_args(
        [command, "frame.png", *extra, FLAGS[field], argv[1]]
        if field != "times"
        else [command, "frame.png", *extra]
    )
    assert capsys.readouterr().err == ""


def test_every_old_name_is_tested() -> None:
    assert {(c, a[0]) for c, a, _, _ in OLD} == {(c, o) for c, d in DEPRECATED.items() for o in d}


@pytest.mark.parametrize("text", ["0", "two", "1.5", "-100000"])
def test_workers_refused_at_parse_time(text: str, capsys) -> None:
    from hdrview.app import build_parser as hdrview_parser

    for argv, parser in (
        (["merge", "f.png", "-o", "o.exr", "--workers", text], build_parser()),
        (["--workers", text], hdrview_parser()),
    ):
        with pytest.raises(SystemExit):
            parser.parse_args(argv)
        assert "expected a number of threads" in capsys.readouterr().err


@pytest.mark.parametrize("text", ["-1", "nan", "x"])
def test_noise_sigma_refused_at_parse_time(text: str, capsys) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["ratios", "f.png", "--noise-sigma", text])
    assert "expected levels, 0 or more" in capsys.readouterr().err


def test_hdrview_workers_reach_every_run() -> None:
    from hdrview.app import build_parser as hdrview_parser
    from hdrview.session import Controls, Session

    assert hdrview_parser().parse_args(["--workers", "-1"]).workers == -1
    session = Session(workers=-1)
    assert session.default_params().workers == -1
    assert session.params_for(Controls(threshold=0.2)).workers == -1
    assert Session().default_params() == PipelineParams()


def _png_bracket(tmp_path: Path, capsys) -> Path:
    out = tmp_path / "sim"
    assert (
        main(
            [
                "simulate",
                str(out),
                "--size",
                "48x64",
                "--bits",
                "8",
                "--format",
                "png",
                "--frames",
                "3",
                "--seed",
                "2",
            ]
        )
        == 0
    )
    capsys.readouterr()
    return out


def test_merge_and_align_pass_workers_to_the_pipeline(tmp_path, capsys, monkeypatch) -> None:
    sim = _png_bracket(tmp_path, capsys)
    rc = main(
        ["merge", str(sim), "-o", str(tmp_path / "o.exr"), "--workers", "-1", "--json", "--quiet"]
    )
    report = json.loads(capsys.readouterr().out)
    assert rc == 0 and report["parameters"]["workers"] == -1

    import hdrcore.cli.align as align_cli

    seen = []
    real = align_cli.Pipeline

    def spy(bracket, params, *a, **k):
        seen.append(params)
        return real(bracket, params, *a, **k)

    monkeypatch.setattr(align_cli, "Pipeline", spy)
    assert main(["align", str(sim), "--workers", "1", "--json"]) == 0
    capsys.readouterr()
    assert [p.workers for p in seen] == [1] and seen[0].align == DEFAULTS["align"]
