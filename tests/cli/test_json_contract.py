"""The README's "JSON outputs" section, held against real output (issue 17, point 6).

The section's blocks are read as a schema: ``"key"`` alone must be present; ``"key": N`` an
integer; ``"a" | "b"`` one of those strings; ``null | {...}`` either; ``[{...}...]`` a list of
such objects; ``...`` inside an object: more keys may follow. Every key a block documents must
be in the real document with that type, and every top-level key of the real document must be
documented. Runs ``hdrcore merge --report`` and ``hdrcore align --json`` on the demo bracket
(``assets/demo``, local refinement on so that its part of the schema is exercised too) and
``hdrcore ratios --json`` and ``info --json`` on a small simulated one.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from hdrcore.cli import main

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DEMO = ROOT / "assets" / "demo"

# -- the README's pseudo-JSON ------------------------------------------------------------------


class Schema:
    """``kind``: any, int, null, strings (``values``), list (``item``), object (``keys``,
    ``open``), union (``options``)."""

    def __init__(self, kind: str, **kw: Any) -> None:
        self.kind, self.__dict__ = kind, {"kind": kind, **kw}

    def __repr__(self) -> str:
        return f"Schema({self.__dict__})"


ANY = Schema("any")


class _Reader:
    def __init__(self, text: str) -> None:
        self.s, self.i = text, 0

    def ws(self) -> None:
        while self.i < len(self.s) and self.s[self.i].isspace():
            self.i += 1

    def peek(self, token: str) -> bool:
        self.ws()
        return self.s.startswith(token, self.i)

    def take(self, token: str) -> bool:
        if self.peek(token):
            self.i += len(token)
            return True
        return False

    def string(self) -> str:
        self.ws()
        if self.s[self.i] != '"':
            raise ValueError(f"expected a quoted key at {self.s[self.i : self.i + 30]!r}")
        end = self.s.index('"', self.i + 1)
        text, self.i = self.s[self.i + 1 : end], end + 1
        return text

    def value(self) -> Schema:
        options = [self.single()]
        while self.take("|"):
            options.append(self.single())
        strings = [o for o in options if o.kind == "strings"]
        if len(strings) > 1:  # "a" | "b": one enumeration
            options = [o for o in options if o.kind != "strings"] + [
                Schema("strings", values=[v for o in strings for v in o.values])
            ]
        return options[0] if len(options) == 1 else Schema("union", options=options)

    def single(self) -> Schema:
        if self.peek("{"):
            return self.obj()
        if self.peek("["):
            return self.lst()
        if self.take("null"):
            return Schema("null")
        if self.peek('"'):
            return Schema("strings", values=[self.string()])
        m = re.compile(r"[^,\]\}|]*").match(self.s, self.i)
        word = m.group(0).strip()
        self.i = m.end()
        return Schema("int") if word == "N" else ANY

    def obj(self) -> Schema:
        self.take("{")
        keys: dict[str, Schema] = {}
        open_ = False
        while not self.take("}"):
            if self.take("..."):
                open_ = True
            else:
                key = self.string()
                keys[key] = self.value() if self.take(":") else ANY
            self.take(",")
        return Schema("object", keys=keys, open=open_)

    def lst(self) -> Schema:
        self.take("[")
        if self.peek("{") or self.peek("[") or self.peek('"'):
            item = self.value()
            self.take("...")
            while self.take(","):  # [[a, b, c], [d, e, f]]: rows alike
                self.value()
            if not self.take("]"):
                raise ValueError(f"unclosed list at {self.s[self.i : self.i + 30]!r}")
            return Schema("list", item=item)
        depth = 1  # [3x3], [matrix per frame], [...]: a list of anything
        while depth:
            depth += {"[": 1, "]": -1}.get(self.s[self.i], 0)
            self.i += 1
        return Schema("list", item=ANY)


def readme_blocks(text: str) -> dict[str, Schema]:
    """``{command: schema}`` of each block of the JSON section, named by the ``hdrcore
    <command>`` that introduces it."""
    section = text.split("\n## JSON outputs", 1)[1].split("\n## ", 1)[0]
    blocks: dict[str, Schema] = {}
    for m in re.finditer(r"```\n(.*?)```", section, re.S):
        intro = re.findall(r"`hdrcore (\w+)", section[: m.start()])
        reader = _Reader(m.group(1))
        blocks[intro[-1]] = reader.value()
        reader.ws()
        assert reader.i == len(reader.s), f"{intro[-1]}: left over {reader.s[reader.i :]!r}"
    return blocks


# -- the check ---------------------------------------------------------------------------------


def mismatches(value: Any, schema: Schema, where: str = "") -> list[str]:
    """What in ``value`` departs from ``schema`` (empty: it matches)."""
    k = schema.kind
    if k == "any":
        return []
    if k == "null":
        return [] if value is None else [f"{where}: {value!r} is not null"]
    if k == "int":
        ok = isinstance(value, int) and not isinstance(value, bool)
        return [] if ok else [f"{where}: {value!r} is not an integer"]
    if k == "strings":
        return [] if value in schema.values else [f"{where}: {value!r} not in {schema.values}"]
    if k == "union":
        found = [mismatches(value, o, where) for o in schema.options]
        return [] if any(not f for f in found) else [f for fs in found for f in fs]
    if k == "list":
        if not isinstance(value, list):
            return [f"{where}: {type(value).__name__}, not a list"]
        return [e for n, v in enumerate(value) for e in mismatches(v, schema.item, f"{where}[{n}]")]
    if not isinstance(value, dict):
        return [f"{where}: {type(value).__name__}, not an object"]
    out = [f"{where}.{key}: missing" for key in schema.keys if key not in value]
    for key, sub in schema.keys.items():
        if key in value:
            out += mismatches(value[key], sub, f"{where}.{key}")
    return out


def check_document(doc: dict, schema: Schema, name: str) -> None:
    """Every documented key present with its type; no top-level key undocumented."""
    assert schema.kind == "object", name
    problems = mismatches(doc, schema, name)
    undocumented = sorted(set(doc) - set(schema.keys))
    assert not problems, "\n".join(problems)
    assert not undocumented, f"{name}: top-level keys the README does not document: {undocumented}"


# -- the parser itself, on made-up text (the contract test below relies on it) -----------------


def test_the_readme_reader_finds_what_is_wrong() -> None:
    schema = _Reader(
        '{"a": N, "b", "c": "x" | "y", "d": null | {"e", ...},\n'
        ' "f": [{"g": [[a, b], [c, d]] | null}...], "h": [3x3 per frame]}'
    ).value()
    good = {
        "a": 1,
        "b": "anything",
        "c": "y",
        "d": {"e": 0, "more": 1},
        "f": [{"g": None}, {"g": [[1, 2], [3, 4]]}],
        "h": [],
    }
    assert mismatches(good, schema) == []
    assert mismatches({**good, "d": None}, schema) == []
    bad = {**good, "a": 1.5, "c": "z", "d": {"x": 1}, "f": [{"g": 3}]}
    del bad["b"]
    found = "\n".join(mismatches(bad, schema, "doc"))
    for expected in (
        "doc.a: 1.5 is not an integer",
        "doc.b: missing",
        "doc.c: 'z' not in",
        "doc.d.e: missing",
        "doc.f[0].g: int, not a list",
    ):
        assert expected in found
    with pytest.raises(AssertionError, match="does not document: .'zz'."):
        check_document({**good, "zz": 1}, schema, "doc")


# -- the contract ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def blocks() -> dict[str, Schema]:
    return readme_blocks(README.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def demo_outputs(tmp_path_factory) -> tuple[dict, dict]:
    """``merge --report`` and ``align --json`` of the demo bracket (local refinement on)."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("demo")
    assert (
        main(
            [
                "merge",
                str(DEMO),
                "-o",
                str(out / "demo.exr"),
                "--report",
                str(out / "demo.json"),
                "--local",
                "on",
                "--quiet",
            ]
        )
        == 0
    )
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(["align", str(DEMO), "--local", "on", "--json"]) == 0
    return json.loads((out / "demo.json").read_text()), json.loads(stdout.getvalue())


def test_readme_documents_each_command(blocks) -> None:
    assert {"info", "ratios", "align", "response", "merge"} <= set(blocks)


def test_align_json_is_as_documented(blocks, demo_outputs) -> None:
    _, aligned = demo_outputs
    assert aligned["local"] is not None and aligned["local"]["frames"]  # the schema's branch
    check_document(aligned, blocks["align"], "align --json")


def test_merge_report_is_as_documented(blocks, demo_outputs) -> None:
    report, aligned = demo_outputs
    check_document(report, blocks["merge"], "merge --report")
    # "registration: the document of align --json" (one serialiser): the same keys at every
    # level, but for the frames lists align adds
    schema = blocks["align"]
    reg_schema = Schema(
        "object",
        keys={k: v for k, v in schema.keys.items() if k not in ("frames", "frames_not_used")},
        open=False,
    )
    check_document(report["registration"], reg_schema, "merge --report: registration")
    assert set(report["registration"]) == set(aligned) - {"frames", "frames_not_used"}
    assert set(report["registration"]["pairs"][0]) == set(aligned["pairs"][0])


def test_ratios_and_info_json_are_as_documented(blocks, tmp_path, capsys) -> None:
    sim = tmp_path / "sim"
    assert (
        main(
            [
                "simulate",
                str(sim),
                "--size",
                "48x64",
                "--bits",
                "8",
                "--format",
                "png",
                "--frames",
                "3",
                "--seed",
                "1",
            ]
        )
        == 0
    )
    capsys.readouterr()
    main(["ratios", str(sim), "--times", str(sim / "exposure_times.txt"), "--json"])
    check_document(json.loads(capsys.readouterr().out), blocks["ratios"], "ratios --json")
    assert main(["info", str(sim), "--json"]) == 0
    check_document(json.loads(capsys.readouterr().out), blocks["info"], "info --json")
