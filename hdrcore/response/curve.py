"""The camera response object shared by every recovery method and every later stage.

A :class:`ResponseCurve` holds the *inverse* camera response ``g`` of each colour channel sampled
at every integer output level ``0 .. max_level``: ``g(z)`` is the linear exposure (irradiance
times exposure time, up to one common scale) that produced level ``z``. It is normalised so that
``g(0) = 0`` and ``g(max_level) = 1`` and is non-decreasing (Cerman & Hlavac 2006, section 4,
ask for monotone responses; every method here enforces it).

The exposure-ratio estimator and the merge take :meth:`ResponseCurve.to_lut`; frames are
linearised with :meth:`ResponseCurve.apply`. The object also carries its diagnostics (method,
exposure ratios used or estimated, residuals, a status and a human message) so the browser
inspector can draw them without recomputing anything.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, ParameterError
from ..status import ResponseStatus, is_response_status

__all__ = ["ChannelFit", "ResponseCurve", "normalise_curve", "FORMAT_VERSION"]

FORMAT_VERSION = 1


@dataclass(frozen=True)
class ChannelFit:
    """Diagnostics of one channel's fit.

    ``residual_rms`` is the RMS of the weighted data residuals of the method's own objective;
    ``order`` the polynomial order (``None`` for non-parametric curves); ``active_constraints``
    how many monotonicity constraints were binding; ``exposure_ratios`` the consecutive ratios
    ``t[k+1] / t[k]`` this channel used (given) or estimated; ``non_monotone_steps`` how many
    level steps of an unconstrained fit went down (then repaired by a running maximum).
    """

    residual_rms: float
    n_constraints: int
    exposure_ratios: tuple[float, ...]
    order: int | None = None
    active_constraints: int = 0
    iterations: int = 0
    order_scores: tuple[tuple[int, float], ...] = ()
    non_monotone_steps: int = 0

    def to_json(self) -> dict[str, Any]:
        return {
            "residual_rms": float(self.residual_rms),
            "n_constraints": int(self.n_constraints),
            "exposure_ratios": [float(r) for r in self.exposure_ratios],
            "order": self.order,
            "active_constraints": int(self.active_constraints),
            "iterations": int(self.iterations),
            "order_scores": [[int(o), float(s)] for o, s in self.order_scores],
            "non_monotone_steps": int(self.non_monotone_steps),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ChannelFit:
        return cls(
            residual_rms=float(d.get("residual_rms", float("nan"))),
            n_constraints=int(d.get("n_constraints", 0)),
            exposure_ratios=tuple(float(r) for r in d.get("exposure_ratios", ())),
            order=None if d.get("order") is None else int(d["order"]),
            active_constraints=int(d.get("active_constraints", 0)),
            iterations=int(d.get("iterations", 0)),
            order_scores=tuple((int(o), float(s)) for o, s in d.get("order_scores", ())),
            non_monotone_steps=int(d.get("non_monotone_steps", 0)),
        )


def normalise_curve(g: np.ndarray) -> np.ndarray:
    """Force ``g(0) = 0``, ``g(max) = 1`` and non-decreasing order along the last axis."""
    g = np.array(g, dtype=np.float64)
    if g.ndim == 1:
        g = g[None]
    if g.shape[-1] < 2:
        raise ParameterError("a response needs at least two levels", found=str(g.shape))
    if not np.all(np.isfinite(g)):
        raise ParameterError("response values must be finite")
    g = np.maximum.accumulate(g, axis=-1)
    lo = g[:, :1]
    hi = g[:, -1:]
    span = hi - lo
    if np.any(span <= 0):
        raise ParameterError("a response must increase somewhere", found="a constant curve")
    return (g - lo) / span


@dataclass(frozen=True, eq=False)
class ResponseCurve:
    """Inverse camera response per channel, sampled at every level, with its diagnostics.

    ``g`` has shape ``(C, max_level + 1)``, float64, ``g[:, 0] == 0``, ``g[:, -1] == 1``,
    non-decreasing along levels. ``residuals`` (optional, ``(C, max_level + 1)``) is the fit's
    weighted mean residual of ``ln g`` at every level (NaN where no data touched it; see
    :func:`hdrcore.response.joint.level_residuals`); ``selection`` the
    :class:`hdrcore.response.select.ResponseSelection` of ``--response auto`` (candidates, their
    held-back scores, the winner, the fallback and why, every candidate's curve and residuals),
    ``None`` for a curve asked for by name. :meth:`to_json` writes both; :meth:`from_json`
    reads the residuals back, not the selection (a saved curve is a curve).
    """

    g: np.ndarray
    method: str
    exposure_ratios: tuple[float, ...] = ()
    channels: tuple[ChannelFit, ...] = ()
    status: ResponseStatus = "ok"
    message: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)
    channel_names: tuple[str, ...] = ()
    residuals: np.ndarray | None = field(default=None, repr=False)
    selection: Any = None

    def __post_init__(self) -> None:
        g = np.asarray(self.g, dtype=np.float64)
        if g.ndim == 1:
            g = g[None]
        if g.ndim != 2 or g.shape[1] < 2:
            raise ParameterError(
                "response table must be (channels, levels)", found=str(np.shape(self.g))
            )
        if not np.all(np.isfinite(g)):
            raise ParameterError("response values must be finite")
        if np.any(np.diff(g, axis=1) < -1e-12):
            raise ParameterError("response must be non-decreasing in the level")
        if not (np.allclose(g[:, 0], 0.0, atol=1e-9) and np.allclose(g[:, -1], 1.0, atol=1e-9)):
            raise ParameterError(
                "response must be normalised",
                expected="g(0) = 0 and g(max_level) = 1",
                found=f"g(0) = {g[:, 0].tolist()}, g(max) = {g[:, -1].tolist()}",
            )
        g = g.copy()
        g.setflags(write=False)
        object.__setattr__(self, "g", g)
        if self.residuals is not None:
            r = np.array(self.residuals, dtype=np.float64)
            if r.shape != g.shape:
                raise ParameterError(
                    "residuals must be (channels, levels) like g",
                    expected=str(g.shape),
                    found=str(r.shape),
                )
            r.setflags(write=False)
            object.__setattr__(self, "residuals", r)
        if not self.channel_names:
            names = ("R", "G", "B") if g.shape[0] == 3 else tuple(f"c{k}" for k in range(len(g)))
            object.__setattr__(self, "channel_names", names)

    # -- shape ------------------------------------------------------------------------------
    @property
    def n_channels(self) -> int:
        return int(self.g.shape[0])

    @property
    def max_level(self) -> int:
        return int(self.g.shape[1] - 1)

    @property
    def levels(self) -> np.ndarray:
        return np.arange(self.max_level + 1)

    @property
    def is_monotone(self) -> bool:
        return bool(np.all(np.diff(self.g, axis=1) >= 0))

    # -- evaluation -------------------------------------------------------------------------
    def _channels(self, channel: int | None, n: int) -> list[int]:
        if channel is not None:
            if not 0 <= channel < self.n_channels:
                raise ParameterError(
                    "channel out of range", expected=f"0..{self.n_channels - 1}", found=str(channel)
                )
            return [channel] * n
        if n == self.n_channels:
            return list(range(n))
        if self.n_channels == 1:
            return [0] * n
        raise ParameterError(
            "levels must end in the channel axis",
            expected=f"{self.n_channels} channels",
            found=f"{n}",
        )

    def evaluate(self, levels: np.ndarray | float, channel: int | None = None) -> np.ndarray:
        """Linear exposure ``g(levels)``; fractional levels are interpolated linearly.

        With ``channel`` given, ``levels`` may have any shape; otherwise the last axis of
        ``levels`` is the channel axis.
        """
        z = np.asarray(levels, dtype=np.float64)
        x = self.levels.astype(np.float64)
        if channel is not None:
            (c,) = self._channels(channel, 1)
            return np.interp(z, x, self.g[c])
        if z.ndim == 0:
            raise ParameterError("give channel= for a scalar level")
        out = np.empty_like(z)
        for k, c in enumerate(self._channels(None, z.shape[-1])):
            out[..., k] = np.interp(z[..., k], x, self.g[c])
        return out

    def invert(self, values: np.ndarray | float, channel: int | None = None) -> np.ndarray:
        """Fractional level whose exposure is ``values`` (inverse of :meth:`evaluate`).

        Flat parts of ``g`` (levels that carry no information, e.g. above the saturation cut)
        map to their lowest level.
        """
        v = np.asarray(values, dtype=np.float64)
        x = self.levels.astype(np.float64)

        def inv(c: int, vv: np.ndarray) -> np.ndarray:
            gc = self.g[c]
            # strictly increasing copy for np.interp: keep the first level of each flat run
            keep = np.concatenate([[True], np.diff(gc) > 0])
            return np.interp(vv, gc[keep], x[keep])

        if channel is not None:
            (c,) = self._channels(channel, 1)
            return inv(c, v)
        if v.ndim == 0:
            raise ParameterError("give channel= for a scalar value")
        out = np.empty_like(v)
        for k, c in enumerate(self._channels(None, v.shape[-1])):
            out[..., k] = inv(c, v[..., k])
        return out

    def to_lut(self, max_level: int | None = None) -> np.ndarray:
        """Look-up table ``(C, max_level + 1)`` float64 of ``g`` at integer levels.

        A different ``max_level`` resamples the curve in normalised level ``z / max_level``
        (e.g. an 8-bit curve used for a 12-bit frame).
        """
        if max_level is None or int(max_level) == self.max_level:
            return np.array(self.g, dtype=np.float64)
        m = int(max_level)
        if m < 1:
            raise ParameterError("max_level must be >= 1", found=str(m))
        z = np.arange(m + 1) * (self.max_level / m)
        return np.stack([self.evaluate(z, channel=c) for c in range(self.n_channels)])

    def apply(self, frames: np.ndarray | Sequence[np.ndarray], max_level: int | None = None):
        """Integer levels ``(H, W, C)`` (or a sequence of them) -> float32 linear exposure.

        ``max_level`` defaults to the curve's own; levels above it are clipped.
        """
        if isinstance(frames, (list, tuple)):
            return [self.apply(f, max_level) for f in frames]
        a = np.asarray(frames)
        if not np.issubdtype(a.dtype, np.integer):
            raise ParameterError(
                "frames must hold integer levels", expected="an integer dtype", found=str(a.dtype)
            )
        m = self.max_level if max_level is None else int(max_level)
        lut = self.to_lut(m).astype(np.float32)
        idx = np.clip(a, 0, m).astype(np.intp)
        if a.ndim == 2:
            if self.n_channels != 1:
                raise ParameterError(
                    "a single-channel frame needs a single-channel response",
                    found=f"{self.n_channels} channels",
                )
            return lut[0][idx]
        chans = self._channels(None, a.shape[-1])
        out = np.empty(a.shape, np.float32)
        for k, c in enumerate(chans):
            out[..., k] = lut[c][idx[..., k]]
        return out

    # -- persistence ------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict (``g`` sampled at every level, the diagnostics, the parameters)."""
        return {
            "format": "hdrcore.response",
            "version": FORMAT_VERSION,
            "method": self.method,
            "max_level": self.max_level,
            "exposure_ratios": [float(r) for r in self.exposure_ratios],
            "status": self.status,
            "message": self.message,
            "parameters": _jsonable(self.parameters),
            "channels": [
                {
                    "name": self.channel_names[c],
                    "levels": self.levels.tolist(),
                    "g": [float(v) for v in self.g[c]],
                    "fit": self.channels[c].to_json() if c < len(self.channels) else None,
                    "residuals": None
                    if self.residuals is None
                    else [None if not np.isfinite(v) else float(v) for v in self.residuals[c]],
                }
                for c in range(self.n_channels)
            ],
            "selection": None if self.selection is None else self.selection.to_json(),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any], *, path: str | os.PathLike | None = None):
        try:
            chans = d["channels"]
            g = np.array([c["g"] for c in chans], dtype=np.float64)
            fits = tuple(ChannelFit.from_json(c["fit"]) for c in chans if c.get("fit") is not None)
            res = None
            if all(c.get("residuals") is not None for c in chans):
                res = np.array(
                    [[np.nan if v is None else float(v) for v in c["residuals"]] for c in chans],
                    dtype=np.float64,
                )
            status = d.get("status", "ok")
            if not is_response_status(status):
                raise ValueError(f"unknown status {status!r}")
            return cls(
                g=g,
                method=str(d.get("method", "unknown")),
                exposure_ratios=tuple(float(r) for r in d.get("exposure_ratios", ())),
                channels=fits if len(fits) == len(chans) else (),
                status=status,
                message=str(d.get("message", "")),
                parameters=dict(d.get("parameters", {})),
                channel_names=tuple(str(c.get("name", f"c{k}")) for k, c in enumerate(chans)),
                residuals=res,
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, ParameterError):
                raise InputError(f"not a valid response curve: {exc.reason}", path=path) from exc
            raise InputError(
                "not a response curve JSON",
                path=path,
                expected="an object with 'channels': [{'g': [...]}, ...]",
                found=repr(exc),
            ) from exc

    def save(
        self,
        path: str | os.PathLike,
        *,
        force: bool = False,
        inputs: Sequence[str | os.PathLike] = (),
    ) -> Path:
        """Write JSON atomically; refuses to replace an existing file unless ``force``."""
        from ..io.atomic import atomic_write

        text = json.dumps(self.to_json(), indent=2)
        return atomic_write(path, lambda p: Path(p).write_text(text), force=force, inputs=inputs)

    @classmethod
    def load(cls, path: str | os.PathLike) -> ResponseCurve:
        p = Path(path)
        if not p.is_file():
            raise InputError("response curve file not found", path=p)
        try:
            d = json.loads(p.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError("cannot read response curve JSON", path=p, found=str(exc)) from exc
        if not isinstance(d, dict):
            raise InputError("not a response curve JSON", path=p, found=type(d).__name__)
        return cls.from_json(d, path=p)

    def plot(
        self,
        path: str | os.PathLike,
        *,
        force: bool = False,
        title: str | None = None,
        inputs: Sequence[str | os.PathLike] = (),
    ) -> Path:
        """Draw ``g`` of every channel (levels on x, linear exposure on y) into a PNG."""
        from .plot import plot_curves

        return plot_curves(
            [(self, self.method)],
            path,
            force=force,
            title=title or f"response: {self.method}",
            inputs=inputs,
        )


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if obj is None or isinstance(obj, (str, int, float, bool)):
        return obj
    return str(obj)
