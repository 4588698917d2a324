"""hdrcore._memory: the programs' allocator setting, and its off switch."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from hdrcore._memory import retain_freed_memory


def test_off_switch(monkeypatch) -> None:
    monkeypatch.setenv("HDRCORE_RETAIN_MEMORY", "0")
    assert retain_freed_memory() is False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc setting")
def test_setting_applies_in_a_program_and_memory_still_works() -> None:
    code = (
        "import numpy as np\n"
        "from hdrcore._memory import retain_freed_memory\n"
        "ok = retain_freed_memory()\n"
        "a = np.ones(50_000_000, np.uint8); del a\n"
        "b = np.zeros(60_000_000, np.uint8); assert not b.any()\n"
        "print(ok)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout.strip()
    glibc = platform.libc_ver()[0] == "glibc"
    assert out == ("True" if glibc else "False")
