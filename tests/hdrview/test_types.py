"""The inspector against the library's real types (issue 17): its controls are
:class:`~hdrcore.pipeline.PipelineParams` fields, it draws :class:`PipelineResult` fields, and the
pipeline stays out of its start-up."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import typing
from pathlib import Path

from hdrcore.pipeline import PipelineParams
from hdrview.session import Controls, Session
from hdrview.view import ClientView, _registry_names

ROOT = Path(__file__).resolve().parents[2]


def test_every_control_is_a_pipeline_parameter() -> None:
    params = typing.get_type_hints(PipelineParams)
    for f in dataclasses.fields(Controls):
        assert f.name in params, f.name
    set_all = Controls(
        saturation=240.0,
        noise_floor=3.0,
        threshold=0.2,
        align="similarity",
        local="off",
        reference=1,
        response="srgb",
        tonemap="reinhard",
        tonemap_exposure=1.5,
        deghost=True,
        times="exif",
        exposure_method="Cerman 2006",
    )
    p = Session(workers=1).params_for(set_all)
    for name, value in set_all.changes().items():
        assert getattr(p, name) == value, name
    assert p.workers == 1
    # every dropdown lists the choices of the parameter of its name
    assert set(_registry_names()) <= params.keys()


def test_the_pipeline_is_not_imported_with_the_inspector() -> None:
    """Its types come from the library for mypy only: the stages (a second or two to import,
    numba's kernels) load on the first run, off the thread that serves the page."""
    code = (
        "import sys; import hdrview.app, hdrview.view, hdrview.panels.result; "
        "print([m for m in ('hdrcore.pipeline', 'hdrcore.registration', "
        "'hdrcore.exposure', 'hdrcore.merge') if m in sys.modules])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=True,
        timeout=120,
    )
    assert out.stdout.strip() == "[]"


def test_sliders_show_the_levels_the_pipeline_used(app: ClientView) -> None:
    """Z is 0.97 x 255 = 247.35 on an 8-bit bracket: the slider shows it (it showed 247, an
    integer slider), and marks it as the default on the page (the mark never reached it)."""
    assert app.request_path("bracket")
    assert app.wait_idle(60)
    result = app.session.result
    assert result is not None
    for handle, used in (
        (app.saturation_slider, result.saturation),
        (app.noise_slider, result.noise_floor),
    ):
        # the noise floor of this gamma bracket (21.1) is above the slider's 8-bit range (16):
        # the slider showed the previous value and now widens to take it
        assert handle.min <= used <= handle.max and handle.value == round(used, 2)
        marks = handle._marks
        assert marks is not None and [(m.value, m.label) for m in marks] == [(used, "default")]
    assert app.saturation_slider.value == 247.35  # an integer slider showed 247
    assert result.noise_floor > 16 and app.noise_slider.value == round(result.noise_floor, 2)


def test_slider_boxes_keep_their_values_within_six_characters() -> None:
    """The box beside a slider shows six characters whole ("464.56"): two decimals while they
    fit (247.35), one for a 12-bit Z (3723.83 showed "3723.8" cut off), none for 16 bits."""
    from hdrview.view import BOX_CHARACTERS, _box_decimals

    for used, decimals in ((247.35, 2), (3723.83, 1), (63568.95, 0), (464.56, 2), (12.5, 2)):
        assert _box_decimals(used) == decimals
        assert len(f"{round(used, decimals):.{decimals}f}") <= BOX_CHARACTERS
