"""hdrview's controls tell the truth (issue 16), in a real browser: sliders start at the values
the pipeline used, reset works, two pages keep their own state, the result can be read at 100 %,
every dropdown option reaches the result, plots fit the window. Screenshots as artefacts."""

from __future__ import annotations

import re

import pytest

from hdrview.view import BOX_CHARACTERS, DEFAULT_MARK, ClientView, _box_decimals

from .conftest import ARTIFACTS
from .test_inspector import TIMEOUT, labelled, open_tab, text_field, wait_until

pytestmark = pytest.mark.e2e


def slider_value(page, label: str) -> float:
    return float(labelled(page, label).locator("[role=slider]").get_attribute("aria-valuenow"))


def choose(page, label: str, option: str) -> None:
    """Pick ``option`` in the viser dropdown labelled ``label`` (a Mantine Select)."""
    lab = page.locator("label").filter(has_text=re.compile(rf"^{re.escape(label)}$")).first
    field = page.locator(f"[id='{lab.get_attribute('for')}']")
    field.click()
    page.get_by_role("option", name=option, exact=True).first.click()


def loaded(view: ClientView) -> bool:
    return view.session.result is not None and view.wait_idle(0.01)


def test_sliders_start_at_the_values_the_pipeline_used(page, view: ClientView) -> None:
    wait_until(lambda: loaded(view), TIMEOUT, "the demo's result")
    r = view.session.result
    page.wait_for_timeout(500)
    # The slider keeps whole levels (its step); the box next to it and the status line say the
    # value to 0.01 level, marked as the default.
    wait_until(
        lambda: abs(slider_value(page, "Saturation Z") - r.saturation) <= 1.0,
        10,
        "Saturation Z to show the pipeline's Z",
    )
    assert abs(slider_value(page, "Noise floor") - r.noise_floor) <= 1.0
    # the number box beside each slider reads the value itself, not the slider's step (the
    # demo's 12-bit Z 3723.83 once read "3724", the memorial's 247.35 "247"), to 0.01 level as
    # far as its six visible characters go (3723.83 was cut off: it reads 3723.8)
    for label, used in (("Saturation Z", r.saturation), ("Noise floor", r.noise_floor)):
        box = text_field(page, label).and_(page.locator("input:not([type=hidden])"))
        shown = round(float(used), _box_decimals(float(used)))
        wait_until(
            lambda box=box, shown=shown: float(box.input_value()) == shown,
            10,
            f"the {label} box to read {shown}",
        )
        assert len(box.input_value()) <= BOX_CHARACTERS
    assert slider_value(page, "Threshold t") == pytest.approx(r.params.threshold)
    assert slider_value(page, "Exposure (EV)") == pytest.approx(r.params.tonemap_exposure)
    page.get_by_text(re.compile(rf"Z = {r.saturation:.6g} \(default\)")).first.wait_for(
        state="visible", timeout=10_000
    )
    page.screenshot(path=str(ARTIFACTS / "hdrview-controls-initial.png"))


def test_reset_to_defaults(page, view: ClientView) -> None:
    wait_until(lambda: loaded(view), TIMEOUT, "the result")
    thumb = labelled(page, "Threshold t").locator("[role=slider]")
    thumb.focus()
    for _ in range(3):
        page.keyboard.press("ArrowRight")
    # every press on the server (the slider sends its value every 50 ms) before the reset
    wait_until(
        lambda: (
            view.controls.threshold is not None
            and view.controls.threshold == pytest.approx(slider_value(page, "Threshold t"))
        ),
        15,
        "t to change on the page and the server",
    )
    assert view.wait_idle(TIMEOUT)
    assert slider_value(page, "Threshold t") > 0.1
    page.get_by_role("button", name="Reset to defaults").click()
    wait_until(lambda: view.controls.threshold is None, 15, "the reset")
    assert view.wait_idle(TIMEOUT)
    wait_until(
        lambda: slider_value(page, "Threshold t") == pytest.approx(0.1),
        10,
        "the slider back at 0.1",
    )
    assert view.session.result.params.threshold == pytest.approx(0.1)


def test_two_pages_keep_separate_states(browser, page, view: ClientView, inspector) -> None:
    wait_until(lambda: loaded(view), TIMEOUT, "the first page's result")
    ctx = browser.new_context(viewport={"width": 1600, "height": 1000})
    try:
        other_page = ctx.new_page()
        other_page.goto(inspector.url)
        wait_until(lambda: len(inspector.page_views()) == 2, 30, "the second page")
        other = next(v for v in inspector.page_views() if v is not view)
        wait_until(lambda: loaded(other), TIMEOUT, "the second page's result")
        # The second page loads another bracket and moves a slider; the first keeps its own.
        lab = other_page.locator("label").filter(has_text=re.compile("^Path$")).first
        lab.locator("xpath=ancestor::div[contains(@class,'mantine-Flex-root')][1]//input").fill(
            "small"
        )
        other_page.get_by_role("button", name="Load", exact=True).click()
        wait_until(lambda: other.session.source == "small", TIMEOUT, "the small bracket")
        assert other.wait_idle(TIMEOUT)
        assert view.session.source != "small"
        assert "small" not in " ".join(b for _, _, b in view.notifications)
        other_page.screenshot(path=str(ARTIFACTS / "hdrview-second-page.png"))
    finally:
        ctx.close()
    # The page that left took its state with it; this one still works.
    wait_until(lambda: len(inspector.page_views()) == 1, 15, "the second page to leave")
    assert inspector.page_views()[0] is view


def test_zoom_into_the_result_and_read_a_100_percent_crop(page, view: ClientView) -> None:
    wait_until(lambda: loaded(view), TIMEOUT, "the result")
    open_tab(page, "Result")
    choose(page, "Zoom", "100 %")
    page.get_by_text(re.compile("100 % of the full-resolution result")).first.wait_for(
        state="visible", timeout=15_000
    )
    img = page.locator("img").filter(visible=True).last
    box = img.bounding_box()
    w = view.session.result.radiance.shape[1]
    # One screen pixel per image pixel: the crop is as wide as the box or the whole image.
    natural = img.evaluate("e => e.naturalWidth")
    assert natural == min(w, 880)
    assert box is not None and box["width"] > 100
    page.screenshot(path=str(ARTIFACTS / "hdrview-loupe-100.png"))
    choose(page, "Zoom", "fit")


@pytest.mark.parametrize(
    "label,control,param",
    [
        ("Operator", "tonemap", "tonemap"),
        ("Alignment", "align", "align"),
        ("Ratio method", "exposure_method", "exposure_method"),
    ],
)
def test_each_dropdown_option_reaches_the_result(
    page, view: ClientView, label: str, control: str, param: str
) -> None:
    from hdrview.view import _registry_names

    wait_until(lambda: loaded(view), TIMEOUT, "the result")
    names = _registry_names()[control if control != "tonemap" else "tonemap"]
    default = getattr(view.app.defaults, param)
    previews = {}
    for name in names:
        choose(page, label, name + (DEFAULT_MARK if name == default else ""))
        # Choosing the option already shown (the default, first) sends no change.
        wait_until(
            lambda n=name: (
                getattr(view.controls, control) == n
                or (n == default and getattr(view.controls, control) is None)
            ),
            15,
            f"{label} = {name}",
        )
        assert view.wait_idle(TIMEOUT)
        r = view.session.result
        assert getattr(r.params, param) == name
        previews[name] = r.preview.image if r.preview is not None else None
    if control == "tonemap":  # each operator draws a different picture ("auto" picks one)
        imgs = [p for n, p in previews.items() if p is not None and n != "auto"]
        assert len({p.tobytes() for p in imgs}) == len(imgs)
    page.get_by_role("button", name="Reset to defaults").click()
    wait_until(lambda: getattr(view.controls, control) is None, 15, "the reset")
    assert view.wait_idle(TIMEOUT)


def test_plots_fit_the_window(page, view: ClientView) -> None:
    wait_until(lambda: loaded(view), TIMEOUT, "the result")
    open_tab(page, "BTF")
    plots = page.locator(".js-plotly-plot").filter(visible=True)
    plots.first.wait_for(state="visible", timeout=30_000)
    vp = page.viewport_size
    for k in range(plots.count()):
        b = plots.nth(k).bounding_box()
        assert b is not None
        assert b["height"] < b["width"], "a plot taller than wide"
        assert b["height"] <= 0.8 * vp["height"]
    page.screenshot(path=str(ARTIFACTS / "hdrview-btf-fit.png"))
