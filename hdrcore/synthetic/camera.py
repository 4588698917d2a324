"""Forward camera model of the seed's experiments (Cerman & Hlavac 2006, sections 4.2 and 5.3).

A frame is made from a radiance map ``E`` as ``M = q(f(s(E * dt * key)) + n)`` where ``s`` clips at
the saturation level (1.0), ``f`` is the camera response, ``n`` Gaussian noise of ``noise_sigma``
output levels (optionally with photon shot noise before ``f``), and ``q`` rounds to ``bits`` and
clips to the valid range. Hand-held motion moves each frame by a rigid transform (shift and
rotation about the image centre) relative to the reference frame.

Motion convention (used by every stage of the project): a 2x3 affine matrix ``A`` maps pixel
coordinates ``(x, y, 1)`` of one frame to pixel coordinates of another; x to the right, y down,
origin at the centre of the top-left pixel. For a consecutive pair (dark ``i``, bright ``j``) the
pair matrix maps coordinates of the brighter frame ``j`` to the darker frame ``i``.

Reference: J. Cerman, V. Hlavac, "Exposure time estimation for high dynamic range imaging with
hand held camera", Computer Vision Winter Workshop, 2006.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ..errors import ParameterError, validate_method
from ..geometry import compose, invert, rigid_matrix
from .scenes import make_scene

__all__ = [
    "RENDERINGS",
    "RESPONSES",
    "apply_response",
    "rigid_matrix",
    "compose",
    "invert",
    "pair_matrix",
    "SimulatedBracket",
    "simulate_bracket",
]


def _linear(x: np.ndarray) -> np.ndarray:
    return x


def _gamma(x: np.ndarray) -> np.ndarray:
    return np.power(x, 1.0 / 2.2)


def _poly3(x: np.ndarray) -> np.ndarray:
    # A monotone 3rd-order polynomial with f(0) = 0, f(1) = 1 (f'(x) = 2 - 3x + 1.5x^2 > 0).
    return 2.0 * x - 1.5 * x**2 + 0.5 * x**3


def _srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0), 1 / 2.4) - 0.055)


def _s_curve(x: np.ndarray) -> np.ndarray:
    # Film-like S-shape: gamma lift, then a smooth-step contrast curve; monotone, 0->0, 1->1.
    g = np.power(x, 1.0 / 2.0)
    return g * g * (3.0 - 2.0 * g)


def _aces(x: np.ndarray) -> np.ndarray:
    # K. Narkowicz's fit of the ACES reference rendering and output transforms (2016).
    return x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14)


#: Linear exposure that the filmic curve maps to 1.0 (sensor saturation one stop into the
#: shoulder; mid-grey 0.18 lands at level 0.55, sRGB puts it at 0.46).
FILMIC_WHITE = 2.0


def _filmic(x: np.ndarray) -> np.ndarray:
    # Filmic, ACES-like: a toe (slope 0.47 at black, half a linear curve's, rising to 3.9 in
    # the toe's end) and a shoulder (log-log slope 0.13 at saturation).
    return _aces(FILMIC_WHITE * x) / _aces(np.asarray(FILMIC_WHITE))


def _toe_shoulder(x: np.ndarray) -> np.ndarray:
    # A log-logistic (a logistic in log exposure, as film's characteristic curve): toe
    # f ~ x^1.3 near black, shoulder towards saturation, mid-grey 0.18 at level 0.46.
    p, m = 1.3, 0.25
    h = np.power(x, p)
    return h / (h + m**p) * (1.0 + m**p)


RESPONSES: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "linear": _linear,
    "gamma": _gamma,
    "polynomial3": _poly3,
    "srgb": _srgb,
    "s-curve": _s_curve,
    "filmic": _filmic,
    "toe-shoulder": _toe_shoulder,
}


def apply_response(name: str, x: np.ndarray) -> np.ndarray:
    """The named simulated response ``f`` applied to linear values ``x`` in [0, 1]."""
    key = validate_method(name, RESPONSES, "response")
    return RESPONSES[key](np.clip(x, 0.0, 1.0))


def pair_matrix(to_reference: Sequence[np.ndarray], dark: int, bright: int) -> np.ndarray:
    """Matrix mapping pixel coordinates of frame ``bright`` to frame ``dark``.

    ``to_reference[k]`` maps coordinates of frame ``k`` to the reference frame.
    """
    return compose(invert(to_reference[dark]), to_reference[bright])


@dataclass(frozen=True, eq=False)
class SimulatedBracket:
    """A simulated bracket and its ground truth.

    ``frames[k]`` are integer output levels ``(H, W, 3)`` uint16 at ``bits``; ``radiance`` is the
    scene radiance in reference-frame coordinates (the value a perfect merge would return, in units
    where a frame of exposure ``t`` records ``radiance * t * key`` before saturation).
    """

    frames: tuple[np.ndarray, ...]
    exposure_times: tuple[float, ...]
    radiance: np.ndarray
    bits: int
    response: str
    noise_sigma: float
    key: float
    to_reference: tuple[np.ndarray, ...]
    reference: int
    scene: str
    seed: int
    shot_noise_full_well: float | None = None
    linear_frames: tuple[np.ndarray, ...] = field(default=(), repr=False)
    rendering: str = "area"

    @property
    def max_level(self) -> int:
        return (1 << self.bits) - 1

    @property
    def ratios(self) -> tuple[float, ...]:
        """True exposure ratios ``t[k+1] / t[k]`` of consecutive frames."""
        t = self.exposure_times
        return tuple(t[k + 1] / t[k] for k in range(len(t) - 1))

    def pair_matrix(self, dark: int, bright: int) -> np.ndarray:
        return pair_matrix(self.to_reference, dark, bright)

    def truth(self) -> dict:
        """JSON-ready ground truth (the content of ``truth.json``)."""
        n = len(self.frames)
        return {
            "scene": self.scene,
            "seed": self.seed,
            "bits": self.bits,
            "max_level": self.max_level,
            "response": self.response,
            "noise_sigma": self.noise_sigma,
            "shot_noise_full_well": self.shot_noise_full_well,
            "rendering": self.rendering,
            "key": self.key,
            "saturation": 1.0,
            "shape": list(self.frames[0].shape[:2]),
            "exposure_times": list(self.exposure_times),
            "ratios": list(self.ratios),
            "reference": self.reference,
            "to_reference": [np.asarray(m).tolist() for m in self.to_reference],
            "pairs": [
                {
                    "dark": k,
                    "bright": k + 1,
                    "ratio": self.ratios[k],
                    "matrix": self.pair_matrix(k, k + 1).tolist(),
                }
                for k in range(n - 1)
            ],
            "motion_convention": (
                "2x3 affine; pair matrix maps pixel coordinates of the brighter frame to the "
                "darker; to_reference maps frame coordinates to the reference frame; x right, "
                "y down, origin at the centre of the top-left pixel"
            ),
        }


def _positions(
    matrix: np.ndarray, shape: tuple[int, int], offset: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """``(ys, xs)``: where each pixel of a frame of ``shape`` lies in the radiance grid."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    xs = matrix[0, 0] * xx + matrix[0, 1] * yy + matrix[0, 2] + offset[0]
    ys = matrix[1, 0] * xx + matrix[1, 1] * yy + matrix[1, 2] + offset[1]
    return ys, xs


def _warp_log(
    radiance_big: np.ndarray,
    matrix: np.ndarray,
    shape: tuple[int, int],
    offset: tuple[float, float],
) -> np.ndarray:
    """Sample ``radiance_big`` at ``matrix @ p + offset`` for every pixel p of a frame of ``shape``.

    The ``"log-cubic"`` rendering: interpolates log radiance with cubic splines (positive, no
    ringing below zero). It leaves an unmoved frame as drawn and changes the local mean
    radiance of a moved one (by up to about 1 % on the scenes' pixel-scale texture and
    four-decade edges: spline overshoot in log is amplified by the exponential), so a moved
    frame is not the same scene at another exposure.
    """
    ys, xs = _positions(matrix, shape, offset)
    out = np.empty((*shape, radiance_big.shape[2]), np.float32)
    for c in range(radiance_big.shape[2]):
        logc = np.log(radiance_big[..., c].astype(np.float64))
        out[..., c] = np.exp(ndimage.map_coordinates(logc, [ys, xs], order=3, mode="nearest"))
    return out


def _render_area(
    radiance_big: np.ndarray,
    matrix: np.ndarray,
    shape: tuple[int, int],
    offset: tuple[float, float],
) -> np.ndarray:
    """The ``"area"`` rendering: what a sensor pixel at ``matrix @ p + offset`` integrates.

    The continuous scene is the bilinear interpolant of the radiance grid; a pixel integrates
    it over its (unit, axis-aligned) footprint. A box convolved with the tent is the quadratic
    B-spline, so every pixel of every frame, moved or not, is
    ``sum_g E[g] * B2(p' - g)`` (``map_coordinates(order=2, prefilter=False)``). The weights are
    non-negative and sum to one: radiance stays positive and its local mean is kept, whatever
    the sub-pixel phase, so frames moved by a hand-held camera remain the same scene at another
    exposure (as on a real sensor). The footprint's rotation (at most a few degrees) is
    neglected.
    """
    ys, xs = _positions(matrix, shape, offset)
    out = np.empty((*shape, radiance_big.shape[2]), np.float32)
    for c in range(radiance_big.shape[2]):
        out[..., c] = ndimage.map_coordinates(
            radiance_big[..., c].astype(np.float64),
            [ys, xs],
            order=2,
            mode="nearest",
            prefilter=False,
        )
    return out


def _local_gain(x: np.ndarray, strength: float) -> np.ndarray:
    """Gain of the simulated local tone mapping (see ``simulate_bracket(local_tonemap=)``)."""
    lum = x @ np.array([0.2126, 0.7152, 0.0722])
    sigma = 0.04 * min(lum.shape)
    local = np.exp(ndimage.gaussian_filter(np.log(np.maximum(lum, 1e-6)), sigma, mode="nearest"))
    return np.clip((0.18 / local) ** float(strength), 0.5, 2.0)


RENDERINGS = ("area", "log-cubic")
"""How :func:`simulate_bracket` renders frames from the radiance grid (see the two renderers)."""


def simulate_bracket(
    radiance: np.ndarray | None = None,
    *,
    scene: str = "window",
    shape: tuple[int, int] = (256, 384),
    exposure_times: Sequence[float] = (1.0, 4.0, 16.0),
    bits: int = 8,
    response: str = "linear",
    noise_sigma: float = 1.0,
    shot_noise_full_well: float | None = None,
    motion: Sequence[tuple[float, float, float]] | None = None,
    max_shift: float = 0.0,
    max_rotation_deg: float = 0.0,
    reference: int | None = None,
    key: float | None = None,
    seed: int = 0,
    keep_linear: bool = False,
    rendering: str = "area",
    local_tonemap: float = 0.0,
) -> SimulatedBracket:
    """Simulate a bracket ``M = q(f(s(E * dt * key)) + n)`` with known truth.

    Parameters
    ----------
    radiance : optional radiance map ``(H, W, 3)``; otherwise ``make_scene(scene, shape, seed)``.
    exposure_times : seconds, any order; frames are returned in the given order.
    bits : 8, 10, 12, 14 or 16 output bits.
    response : a name in :data:`RESPONSES`.
    noise_sigma : Gaussian noise in output levels, added before rounding.
    shot_noise_full_well : if given, photon shot noise for a sensor of this full-well capacity
        (electrons at the saturation level) is added in the linear domain before the response.
    motion : per-frame ``(dx, dy, angle_deg)`` relative to the reference frame, or
    max_shift, max_rotation_deg : random hand-held motion drawn uniformly within these bounds
        (the reference frame stays put).
    reference : index of the frame whose coordinates the radiance truth uses (default: middle).
    key : exposure scale; default puts the median radiance at 0.18 for the geometric-mean time.
    keep_linear : also keep the noiseless linear sensor values (before ``f`` and quantisation).
    local_tonemap : strength ``a`` of a phone-like local tone mapping applied to each frame
        before the response: every pixel's exposure is multiplied by
        ``clip((0.18 / L)^a, 1/2, 2)`` with ``L`` the frame's own local mean exposure (Gaussian
        of 4 % of the image size; the same gain for every channel, so colours are kept).
        Inside the clip range the gain is a power law, outside it is constant, so the transfer
        between two frames varies across the image between ``R^(1 - a)`` and ``R`` (0: off).
    rendering : ``"area"`` (default): when any frame moves, every frame, moved or not,
        integrates the continuous scene over its pixels (:func:`_render_area`), so motion keeps
        the local mean radiance (without motion the frames are the radiance grid itself);
        ``"log-cubic"``: the earlier renderer (:func:`_warp_log`), which leaves unmoved frames
        as drawn and changes the brightness of moved ones by up to about 1 %.
    """
    times = tuple(float(t) for t in exposure_times)
    if len(times) < 1 or any(not np.isfinite(t) or t <= 0 for t in times):
        raise ParameterError("exposure times must be positive", found=str(times))
    if bits not in (8, 10, 12, 14, 16):
        raise ParameterError(
            "unsupported bit depth", expected="8, 10, 12, 14 or 16", found=str(bits)
        )
    if noise_sigma < 0:
        raise ParameterError("noise sigma must be >= 0", found=str(noise_sigma))
    if not (np.isfinite(local_tonemap) and 0 <= local_tonemap < 1):
        raise ParameterError("local_tonemap strength must be in [0, 1)", found=str(local_tonemap))
    validate_method(response, RESPONSES, "response")
    if rendering not in RENDERINGS:
        raise ParameterError(
            "unknown rendering", expected=", ".join(RENDERINGS), found=str(rendering)
        )
    n = len(times)
    ref = n // 2 if reference is None else int(reference)
    if not 0 <= ref < n:
        raise ParameterError("reference frame out of range", expected=f"0..{n - 1}", found=str(ref))
    rng = np.random.default_rng(seed + 7919)

    if motion is None:
        motion = []
        for k in range(n):
            if k == ref or (max_shift == 0 and max_rotation_deg == 0):
                motion.append((0.0, 0.0, 0.0))
            else:
                motion.append(
                    (
                        float(rng.uniform(-max_shift, max_shift)),
                        float(rng.uniform(-max_shift, max_shift)),
                        float(rng.uniform(-max_rotation_deg, max_rotation_deg)),
                    )
                )
    if len(motion) != n:
        raise ParameterError("one motion per frame", expected=str(n), found=str(len(motion)))

    if radiance is None:
        h, w = int(shape[0]), int(shape[1])
        moving = any(m != (0.0, 0.0, 0.0) for m in motion)
        if moving:
            max_disp = max(abs(dx) + abs(dy) for dx, dy, _ in motion)
            max_rot = max(abs(a) for _, _, a in motion)
            margin = int(np.ceil(max_disp + np.deg2rad(max_rot) * (h + w) / 2 + 8))
        else:
            margin = 0
        big = make_scene(scene, (h + 2 * margin, w + 2 * margin), seed)
    else:
        big = np.asarray(radiance, np.float32)
        if big.ndim != 3 or big.shape[2] != 3:
            raise ParameterError("radiance must be (H, W, 3)", found=str(big.shape))
        margin = 0
        h, w = big.shape[:2]
        if np.any(~np.isfinite(big)) or np.any(big <= 0):
            raise ParameterError("radiance must be finite and positive")

    to_ref = tuple(rigid_matrix(dx, dy, a, (h, w)) for dx, dy, a in motion)
    offset = (float(margin), float(margin))
    identity = rigid_matrix(0, 0, 0, (h, w))
    still = all(np.allclose(m, identity) for m in to_ref)

    def render(mat: np.ndarray) -> np.ndarray:
        if rendering == "area" and not still:
            return _render_area(big, mat, (h, w), offset)
        if np.allclose(mat, identity):
            return big[margin : margin + h, margin : margin + w]
        return _warp_log(big, mat, (h, w), offset)

    truth_radiance = np.array(render(to_ref[ref]), np.float32)

    if key is None:
        key = 0.18 / (float(np.median(truth_radiance)) * float(np.exp(np.mean(np.log(times)))))
    max_level = (1 << bits) - 1
    frames = []
    linear_frames = []
    for k, t in enumerate(times):
        e = truth_radiance if k == ref else render(to_ref[k])
        x = e.astype(np.float64) * (t * key)
        if shot_noise_full_well is not None:
            electrons = np.clip(x, 0, 1) * shot_noise_full_well
            x = x + rng.standard_normal(x.shape) * np.sqrt(electrons) / shot_noise_full_well
        if keep_linear:
            linear_frames.append(np.clip(e * (t * key), 0, 1).astype(np.float32))
        if local_tonemap > 0:
            x = x * _local_gain(x, local_tonemap)[..., None]
        y = apply_response(response, np.clip(x, 0.0, 1.0)) * max_level
        if noise_sigma > 0:
            y = y + rng.standard_normal(y.shape) * noise_sigma
        frames.append(np.clip(np.rint(y), 0, max_level).astype(np.uint16))

    return SimulatedBracket(
        frames=tuple(frames),
        exposure_times=times,
        radiance=truth_radiance.astype(np.float32),
        bits=bits,
        response=response,
        noise_sigma=float(noise_sigma),
        key=float(key),
        to_reference=tuple(np.asarray(m) for m in to_ref),
        reference=ref,
        scene=scene if radiance is None else "custom",
        seed=seed,
        shot_noise_full_well=shot_noise_full_well,
        linear_frames=tuple(linear_frames),
        rendering=rendering,
    )
