"""Result objects of registration: the estimate with the diagnostics the inspector draws."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..geometry import affine_part, homogeneous
from ..status import FAILED_REGISTRATION_STATUSES, RegistrationStatus

__all__ = ["PairPreview", "PairRegistration", "BracketRegistration", "FAILED_STATUSES"]

#: Status words of a pair that did not produce a transform (its motion is the identity then).
FAILED_STATUSES = FAILED_REGISTRATION_STATUSES


@dataclass(frozen=True, eq=False)
class PairPreview:
    """Small arrays for drawing one pair (at ``scale`` preview pixels per frame pixel).

    ``overlay_*``: red = bright frame, cyan = dark frame times the exposure ratio (both clipped to
    the range they share, log-scaled), before (identity) and after alignment; uint8 ``(h, w, 3)``;
    grey where the two agree. ``difference_*``: the eq. 7 normalised difference
    ``(a - k b) / max(a + k b, t)`` per pixel, float32 in [-1, 1], NaN where eq. 6 discards the
    pixel (outside the common exposure range or outside the dark frame).
    """

    scale: float
    overlay_before: np.ndarray = field(repr=False)
    overlay_after: np.ndarray = field(repr=False)
    difference_before: np.ndarray = field(repr=False)
    difference_after: np.ndarray = field(repr=False)


@dataclass(frozen=True, eq=False)
class PairRegistration:
    """Registration of one consecutive pair (dark ``i``, bright ``j = i + 1``).

    ``homography`` (3x3, every model) maps pixel coordinates of the bright frame to the dark
    frame (x right, y down, origin at the centre of the top-left pixel; ``(u, v, s) = H (x, y,
    1)``, then ``(u / s, v / s)``); ``matrix`` is the same motion as a 2x3 affine matrix for the
    affine models (shift, euclidean, similarity) and None for ``"homography"``. For an affine
    model ``matrix`` is authoritative: ``homography`` is derived from it (so
    ``dataclasses.replace(pair, matrix=m)`` keeps both in step). ``dx, dy`` are the displacement
    of the image centre, ``angle_deg`` and ``scale`` the rotation and scale of the motion there
    (exactly the parameters of a similarity: rotation and scaling about the image centre, then
    shift). ``cost_before`` / ``cost_after`` are the eq. 6
    cost (mean squared eq. 7 normalised difference over pixels well exposed in both frames) at the
    identity and at the result. ``overlap`` is the fraction of the bright frame that lands inside
    the dark frame (NaN when the pair failed before a start was found); ``valid_fraction`` the
    fraction of the dark frame's pixels that are well exposed in both frames after alignment.
    ``cost_history`` / ``level_history``: the cost at each iteration and the pyramid level it was
    computed on (0 = full resolution). ``initial_shift`` and ``peak_ncc`` / ``peak_psr`` come from
    the eq. 5 step. When ``status`` is not ``"ok"`` the motion is the
    identity and ``message`` says why.
    """

    dark: int
    bright: int
    matrix: np.ndarray | None
    dx: float
    dy: float
    angle_deg: float
    ratio: float
    model: str
    method: str
    cost_before: float
    cost_after: float
    overlap: float
    valid_fraction: float
    iterations: int
    cost_history: tuple[float, ...]
    level_history: tuple[int, ...]
    initial_shift: tuple[float, float]
    peak_ncc: float
    peak_psr: float
    status: RegistrationStatus
    message: str
    shape: tuple[int, int]
    seconds: float = 0.0
    preview: PairPreview | None = field(default=None, repr=False)
    homography: np.ndarray | None = field(default=None, repr=False)
    scale: float = 1.0
    #: the model-independent residual motion after alignment
    #: (:class:`hdrcore.registration.residual.ResidualMotion`), when it was measured
    residual: Any = field(default=None, repr=False)
    #: ``(g0, g1, g2)``: the smooth gain found with the motion (empty when the search had
    #: none): the bright frame matched ``exp(g0 + g1 X + g2 Y)`` times ``ratio`` times the
    #: dark one, ``X, Y`` the offset from the centre over the half-diagonal (see
    #: :attr:`ratio_found`, :attr:`gain_spread`)
    gain: tuple[float, ...] = ()

    @property
    def ratio_found(self) -> float:
        """The exposure ratio at the image centre the search found with the motion
        (``ratio * exp(-g0)``; ``ratio`` when no gain was fitted)."""
        return float(self.ratio * np.exp(-self.gain[0])) if self.gain else float(self.ratio)

    @property
    def gain_spread(self) -> float:
        """How much the brightness ratio of the pair changes from the centre to the corners,
        as a factor (``exp(|(g1, g2)|)``; 1 for a uniform ratio): a phone's local tone
        mapping or vignetting that differs between the frames."""
        return float(np.exp(np.hypot(self.gain[1], self.gain[2]))) if len(self.gain) == 3 else 1.0

    def __post_init__(self) -> None:
        if self.matrix is not None:
            object.__setattr__(self, "matrix", affine_part(self.matrix))
            object.__setattr__(self, "homography", homogeneous(self.matrix))
        elif self.homography is None:
            raise ValueError("a PairRegistration needs a matrix or a homography")
        else:
            object.__setattr__(self, "homography", homogeneous(self.homography))

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def usable(self) -> bool:
        """The motion is used (``ok``, or ``weak``: aligned, but the residual measured after
        alignment is larger than it should be; ``message`` says what is left and where)."""
        return self.status in ("ok", "weak")

    def to_json(self) -> dict:
        return {
            "residual": None if self.residual is None else self.residual.to_json(),
            "dark": self.dark,
            "bright": self.bright,
            "matrix": None if self.matrix is None else np.asarray(self.matrix).tolist(),
            "homography": np.asarray(self.homography).tolist(),
            "dx": self.dx,
            "dy": self.dy,
            "angle_deg": self.angle_deg,
            "scale": self.scale,
            "ratio": self.ratio,
            "model": self.model,
            "method": self.method,
            "cost_before": self.cost_before,
            "cost_after": self.cost_after,
            "overlap": self.overlap,
            "valid_fraction": self.valid_fraction,
            "iterations": self.iterations,
            "cost_history": list(self.cost_history),
            "level_history": list(self.level_history),
            "initial_shift": list(self.initial_shift),
            "peak_ncc": self.peak_ncc,
            "peak_psr": self.peak_psr,
            "status": self.status,
            "message": self.message,
            "seconds": self.seconds,
            "gain": list(self.gain),
            "ratio_found": self.ratio_found,
            "gain_spread": self.gain_spread,
        }


@dataclass(frozen=True, eq=False)
class BracketRegistration:
    """Registration of a whole bracket: consecutive pairs chained to the ``reference`` frame.

    ``to_reference_homography[k]`` (3x3) maps pixel coordinates of frame ``k`` to the reference
    frame; ``to_reference[k]`` is the same as a 2x3 matrix for the affine models (None for
    ``"homography"``; when given it is authoritative and the homographies are derived from it).
    A failed pair contributes the identity to the chain (and ``ok`` is False).
    """

    reference: int
    pairs: tuple[PairRegistration, ...]
    to_reference: tuple[np.ndarray, ...] | None
    model: str
    method: str
    to_reference_homography: tuple[np.ndarray, ...] = ()
    #: local refinement after the global motion
    #: (:class:`hdrcore.registration.local.LocalRefinement`), None when not run
    local: Any = None

    def __post_init__(self) -> None:
        if self.to_reference is not None:
            object.__setattr__(
                self, "to_reference_homography", tuple(homogeneous(m) for m in self.to_reference)
            )

    @property
    def ok(self) -> bool:
        return all(p.ok for p in self.pairs)

    def to_json(self) -> dict:
        return {
            "reference": self.reference,
            "model": self.model,
            "method": self.method,
            "pairs": [p.to_json() for p in self.pairs],
            "to_reference": None
            if self.to_reference is None
            else [np.asarray(m).tolist() for m in self.to_reference],
            "to_reference_homography": [
                np.asarray(m).tolist() for m in self.to_reference_homography
            ],
            "local": None if self.local is None else self.local.to_json(),
        }
