"""Where the panels find each stage's result object on the pipeline's result.

One place to change if the pipeline renames a field; nothing else in ``hdrview`` looks into the
pipeline result's layout.
"""

from __future__ import annotations

from typing import Any

__all__ = ["exposure_of", "registration_of", "merge_of", "preview_of", "verdicts_of", "pick"]


def pick(obj: Any, names: tuple[str, ...]) -> Any:
    """First attribute of ``obj`` among ``names`` that exists and is not ``None``."""
    if obj is None:
        return None
    for name in names:
        value = getattr(obj, name, None)
        if value is not None:
            return value
    return None


def exposure_of(result: Any) -> Any:
    """The :class:`hdrcore.exposure.BracketExposureResult` the merge used."""
    return pick(result, ("exposures", "exposure", "ratios"))


def histogram_exposure_of(result: Any) -> Any:
    """The histogram estimate (the paper's equations of eq. 4 and transfer functions): what
    the BTF and mask panels draw, even when the ratios were measured again after
    registration."""
    return pick(result, ("exposures_histogram", "exposures", "exposure", "ratios"))


def registration_of(result: Any) -> Any:
    """The :class:`hdrcore.registration.BracketRegistration` (``None`` when alignment is off)."""
    return pick(result, ("registration", "alignment"))


def merge_of(result: Any) -> Any:
    """The :class:`hdrcore.merge.MergeResult`."""
    return pick(result, ("merge", "merged"))


def preview_of(result: Any) -> Any:
    """The tonemapped preview as uint8 ``(H, W, 3)`` (or an object holding it as ``image``)."""
    p = pick(result, ("preview", "tonemapped", "tonemap"))
    image = getattr(p, "image", None)
    return image if image is not None else p


def verdicts_of(result: Any) -> tuple:
    v = pick(result, ("verdicts", "verdict"))
    if v is None:
        return ()
    return tuple(v) if isinstance(v, (list, tuple)) else (v,)
