"""numba's cache of hdrcore's kernels goes to the user's cache folder, not beside the modules
(issue 17, point 7), and numba's caching of other code is unchanged."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("numba")

ROOT = Path(__file__).resolve().parents[2]

PROBE = textwrap.dedent("""
    import importlib, json, sys
    sys.path.insert(0, sys.argv[1])
    sys.path.insert(0, sys.argv[2])
    import numpy as np
    from hdrcore import _numba, draft
    import elsewhere  # a module outside hdrcore with a cached numba function
    out = {"dir": str(_numba.cache_dir()), "ours": {}}
    for name in ("hdrcore.draft", "hdrcore.merge.maps", "hdrcore.registration.residual"):
        mod = importlib.import_module(name)
        for attr, fn in vars(mod).items():
            if hasattr(fn, "_cache") and hasattr(fn._cache, "_cache_path"):
                out["ours"][name + "." + attr] = [type(fn._cache._impl.locator).__name__,
                                                  fn._cache._cache_path]
    loc = elsewhere.plus_one._cache._impl.locator
    out["elsewhere"] = [type(loc).__name__, elsewhere.plus_one._cache._cache_path]
    if sys.argv[3] == "compile":
        src = np.zeros((4, 4, 3), np.uint16)
        tab = np.zeros((3, 1), np.float64)
        dst = np.zeros((2, 2, 3), np.float64)
        top = np.zeros((2, 2, 3), np.uint16)
        draft._bin_rows(src, 2, tab, np.zeros(3, np.int64), False, dst, top, 0, 2)
    print(json.dumps(out))
""")


def _probe(tmp_path: Path, env_extra: dict[str, str], compile_: bool = False) -> dict:
    other = tmp_path / "other"
    other.mkdir(exist_ok=True)
    (other / "elsewhere.py").write_text(
        "import numba\n\n@numba.njit(cache=True)\ndef plus_one(x):\n    return x + 1\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    env.update(env_extra)
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, str(ROOT), str(other), "compile" if compile_ else "-"],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_kernels_are_cached_in_the_user_cache_folder(tmp_path: Path) -> None:
    cache = tmp_path / "xdg"
    out = _probe(tmp_path, {"XDG_CACHE_HOME": str(cache)}, compile_=True)
    assert out["dir"] == str(cache / "hdrcore" / "numba")
    assert len(out["ours"]) >= 5, out["ours"]
    for name, (locator, path) in out["ours"].items():
        assert locator == "UserCacheLocator", name
        assert Path(path).is_relative_to(cache / "hdrcore" / "numba"), (name, path)
    written = [p.name for p in (cache / "hdrcore" / "numba").rglob("*") if p.is_file()]
    assert any(n.startswith("draft._bin_rows") and n.endswith(".nbi") for n in written), written
    assert any(n.endswith(".nbc") for n in written), written
    # Other code keeps numba's own place (here: __pycache__ beside its file).
    locator, path = out["elsewhere"]
    assert locator != "UserCacheLocator"
    assert Path(path) == tmp_path / "other" / "__pycache__"


def test_numba_cache_dir_still_wins(tmp_path: Path) -> None:
    chosen = tmp_path / "numba-here"
    out = _probe(
        tmp_path, {"NUMBA_CACHE_DIR": str(chosen), "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    )
    for name, (locator, path) in out["ours"].items():
        assert locator == "UserProvidedCacheLocator", name
        assert Path(path).is_relative_to(chosen), (name, path)
    assert not (tmp_path / "xdg" / "hdrcore").exists()


def test_a_kernels_cache_stamp_covers_every_module_of_the_package(tmp_path, monkeypatch) -> None:
    # numba's own stamp is the function's file alone; a kernel that inlines a helper of another
    # module (the merge kernel, the weightings of hdrcore.merge.weights) kept its stale machine
    # code when only that module changed. The stamp holds a digest of every module.
    from hdrcore import _numba
    from hdrcore.merge import _fused

    if os.environ.get("NUMBA_CACHE_DIR"):
        pytest.skip("NUMBA_CACHE_DIR set: numba's own locator (test_numba_cache_dir_still_wins)")
    locator = _fused.merge_rows._cache._impl.locator
    assert type(locator).__name__ == "UserCacheLocator"
    stamp = locator.get_source_stamp()
    assert stamp[1] == _numba.package_digest()
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("def w(v):\n    return v\n")
    monkeypatch.setattr(_numba, "PACKAGE", pkg)
    digests = []
    for text in ("def w(v):\n    return v\n", "def w(v):\n    return 2 * v\n"):
        (pkg / "sub" / "b.py").write_text(text)
        _numba.package_digest.cache_clear()
        digests.append(_numba.package_digest())
    _numba.package_digest.cache_clear()
    assert digests[0] != digests[1]  # another module's change: another stamp
