"""Path-under-root checks and upload sniffing of the inspector."""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path

import pytest

from hdrcore.errors import InputError
from hdrview.security import (
    PathRefused,
    extract_zip_images,
    resolve_under_root,
    safe_upload_name,
    sniff_upload,
    split_path_field,
)

PNG = b"\x89PNG\r\n\x1a\n" + b"\x00" * 64


def test_relative_path_is_taken_from_root(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    assert resolve_under_root("a", tmp_path) == (tmp_path / "a").resolve()
    assert resolve_under_root(str(tmp_path / "a"), tmp_path) == (tmp_path / "a").resolve()
    assert resolve_under_root(".", tmp_path) == tmp_path.resolve()


@pytest.mark.parametrize("text", ["..", "../x", "/etc/passwd", "a/../../b", "~"])
def test_paths_outside_root_are_refused(tmp_path: Path, text: str) -> None:
    root = tmp_path / "root"
    (root / "a").mkdir(parents=True)
    with pytest.raises(PathRefused, match="outside the folder"):
        resolve_under_root(text, root)


def test_symlink_out_of_root_is_refused(tmp_path: Path) -> None:
    root = tmp_path / "root"
    root.mkdir()
    outside = tmp_path / "secret"
    outside.mkdir()
    os.symlink(outside, root / "link")
    with pytest.raises(PathRefused, match="outside"):
        resolve_under_root("link", root)


def test_sibling_with_common_prefix_is_refused(tmp_path: Path) -> None:
    (tmp_path / "root").mkdir()
    (tmp_path / "root2").mkdir()
    with pytest.raises(PathRefused, match="outside"):
        resolve_under_root(str(tmp_path / "root2"), tmp_path / "root")


@pytest.mark.parametrize("text", ["", "   ", "''"])
def test_empty_path_is_an_input_error(tmp_path: Path, text: str) -> None:
    with pytest.raises(InputError, match="empty path"):
        resolve_under_root(text, tmp_path)


def test_nul_is_refused(tmp_path: Path) -> None:
    with pytest.raises(PathRefused, match="NUL"):
        resolve_under_root("a\x00b", tmp_path)


def test_split_path_field() -> None:
    assert split_path_field(" a.png; b.png ,c.png\n") == ["a.png", "b.png", "c.png"]
    assert split_path_field("  ") == []


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("../../etc/passwd", "passwd"),
        ("..\\..\\x.png", "x.png"),
        (".hidden", "hidden"),
        ("a b$c.png", "a_b_c.png"),
        ("", "upload"),
        ("..", "upload"),
    ],
)
def test_safe_upload_name(name: str, expected: str) -> None:
    assert safe_upload_name(name) == expected


def test_sniff_upload() -> None:
    assert sniff_upload("x.png", PNG) == "png"
    assert sniff_upload("x.bin", b"\xff\xd8\xff\xe0" + b"\0" * 20) == "jpeg"
    assert sniff_upload("x.tif", b"II*\x00" + b"\0" * 20) == "tiff"
    assert sniff_upload("x.dng", b"II*\x00" + b"\0" * 2000) == "raw"
    assert sniff_upload("x.zip", b"PK\x03\x04" + b"\0" * 20) == "zip"
    assert sniff_upload("notes.txt", b"hello world") is None
    assert sniff_upload("fake.png", b"hello world") is None
    assert sniff_upload("tiny.dng", b"abc") is None


def _zip(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for k, v in members.items():
            zf.writestr(k, v)
    return buf.getvalue()


def test_zip_extraction_is_flat_and_skips_non_images(tmp_path: Path) -> None:
    data = _zip(
        {
            "../../evil.png": PNG,
            "dir/b.png": PNG,
            "readme.txt": b"hi",
            "exposure_times.txt": b"evil.png 1\nb.png 2\n",
        }
    )
    out = extract_zip_images(data, tmp_path)
    assert [p.name for p in out] == ["b.png", "evil.png"]
    assert all(p.parent == tmp_path for p in out)
    assert (tmp_path / "exposure_times.txt").is_file()
    assert not (tmp_path / "readme.txt").exists()


def test_broken_zip_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not a valid zip"):
        extract_zip_images(b"PK\x03\x04garbage", tmp_path)


def _markdown_texts(obj, seen=None, depth=0) -> list[str]:
    """Every markdown handle's content reachable from the view and its panels."""
    seen = set() if seen is None else seen
    out: list[str] = []
    if id(obj) in seen or depth > 3:
        return out
    seen.add(id(obj))
    if type(obj).__name__ == "GuiMarkdownHandle":
        out.append(obj.content)
    if type(obj).__module__.startswith("hdrview"):
        for v in vars(obj).values():
            for x in v if isinstance(v, (list, tuple)) else (v,):
                out.extend(_markdown_texts(x, seen, depth + 1))
    return out


def test_file_names_reach_the_page_as_text_not_html(app, bracket_root: Path) -> None:
    """The page renders markdown's raw HTML unsanitised: a folder of frames whose names hold
    markup (frames on disk under the root keep their names; uploads are renamed) put 13
    ``<img>`` elements on the page before names were escaped."""
    hostile = "<img src=x>"
    folder = bracket_root / "bracket"
    for p in sorted(folder.glob("frame*.png")):
        p.rename(folder / f"{hostile}{p.name}")
    (folder / "exposure_times.txt").unlink()  # (its "name seconds" lines split on spaces)
    assert app.request_path("bracket")
    assert app.wait_idle(120)
    assert app.session.result is not None
    texts = _markdown_texts(app)
    assert any("&lt;img src=x&gt;frame0.png" in t for t in texts)  # shown, as text
    assert not any("<img" in t for t in texts)
