"""hdrcore._memory: the programs' allocator setting, and its off switch."""

from __future__ import annotations

import os
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
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    ).stdout.strip()
    glibc = platform.libc_ver()[0] == "glibc"
    assert out == ("True" if glibc else "False")


_RSS_PROBE = (
    "import os, sys, numpy as np\n"
    "from hdrcore._memory import retain_freed_memory\n"
    "set_ = retain_freed_memory()\n"
    "def rss():\n"
    "    with open('/proc/self/statm') as f:\n"
    "        return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')\n"
    "base = rss()\n"
    "a = np.ones(200_000_000, np.uint8)  # touched\n"
    "del a\n"
    "freed = rss() - base\n"
    "b = np.ones(200_000_000, np.uint8)\n"
    "again = rss() - base\n"
    "print(set_, freed, again)\n"
)


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc setting")
@pytest.mark.parametrize("retain", [True, False])
def test_freed_memory_is_kept_and_reused_only_with_the_setting(retain: bool) -> None:
    """What the setting is for: a freed 200 MB buffer stays with the process and the next one
    reuses its pages (no new memory touched); switched off, glibc gives it back at once."""
    env = dict(os.environ, HDRCORE_RETAIN_MEMORY="1" if retain else "0")
    out = subprocess.run(
        [sys.executable, "-c", _RSS_PROBE],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
        env=env,
    ).stdout.split()
    was_set, freed, again = out[0] == "True", int(out[1]), int(out[2])
    assert was_set is retain
    if retain:
        assert freed > 150e6  # kept after del
        assert again < 250e6  # the second buffer reused those pages
    else:
        assert freed < 50e6  # returned to the system
