"""Registration bench (issue 14): ours beside OpenCV AlignMTB, ECC and SIFT + RANSAC, in one run.

Run: ``python bench/bench_registration.py [--quick] [--only sim,moved,real,speed] [--pairs N]``

Methods (the rows of every table, same pairs, same run):

* ``ours <model>``: :func:`hdrcore.registration.register_pair` (method ``"fast"``) with every
  model in :data:`hdrcore.registration.MODELS` (new models are picked up as they land); a pair
  it does not report ``ok`` counts as failed (its status is in the per-pair tables);
* ``AlignMTB``: ``cv2.createAlignMTB().calculateShift`` (integer shift; the ``AlignMTB()``
  constructor crashes), on the 8-bit gamma-encoded green channels (exposure invariant by
  construction; the JPEG levels themselves for real brackets);
* ``ECC euclidean`` / ``ECC homography``: ``cv2.findTransformECC`` (MOTION_EUCLIDEAN /
  MOTION_HOMOGRAPHY) from the identity, coarse to fine over 2x2 block-mean levels from about
  0.1 megapixel up to at most 1.5 megapixels (what makes it converge on 20 px hand-held shifts
  and finish on 9-megapixel frames), the matrix scaled back to full resolution;
* ``SIFT+RANSAC similarity`` / ``SIFT+RANSAC homography``: ``cv2.SIFT_create`` keypoints at
  full resolution, Lowe's ratio test 0.75, ``cv2.estimateAffinePartial2D`` with RANSAC /
  ``cv2.findHomography`` with MAGSAC++ (``cv2.USAC_MAGSAC``), 1 px threshold; both share the same
  keypoints, and each row's time includes them. (Earlier runs halved frames above 3 megapixels
  and used plain RANSAC for the homography: on the Xperia pairs that reference differed from
  this one by 0.02-0.27 px at the corners, on the Pixel 7's, where SIFT keeps only 400-850
  inliers, by 1.4-5 px: there no SIFT variant is a reference to half a pixel.)

ECC and SIFT get the exposure-equalised pair (dark times the exposure ratio, both clipped to the
range they share, log-scaled to 8 bits). cv2 is used only here, never in ``hdrcore``.

Columns:

* ``corner px``: mean / worst over pairs of the four image corners mapped by the estimate and
  by the truth (simulated and moved pairs; the dominant plane's truth for two planes);
* ``residual px``: the misalignment left, measured independently of any model
  (:func:`hdrcore.registration.residual.residual_motion`: median over image tiles of the local
  shift between the aligned frames, phase correlation of gradient images), median over pairs
  and the worst pair; ``none`` is the pair before alignment; ``residual unmeasured`` counts the
  pairs without enough confident tiles (too little texture in the range both frames expose,
  or a misalignment beyond a quarter tile);
* ``ok, res > 1 px``: pairs a method reports ok whose residual exceeds 1 px (issue 14: none;
  ours registers with ``check_residual=True``, so a pair the residual check finds misaligned
  is ``weak``: its motion is still measured, it is not ``ok``; its ``s/pair`` includes the
  check, the speed table does not);
* ``to SIFT-H px``: mean corner distance to the SIFT + RANSAC homography over the pairs where
  SIFT has 500 or more inliers (real brackets);
* ``SIFT-H inliers reprojected px``: on the same pairs, the median distance at which a method's
  motion maps the SIFT homography's own inlier matches (bright keypoint -> dark keypoint), mean
  over the pairs: how well it fits SIFT's data, beside SIFT's own fit of it. Where SIFT's
  corners are poorly determined (inliers in part of the frame only, the corners extrapolated)
  a motion can be far from SIFT's corners while fitting its matches as well;
* ``s/pair`` and ``x MTB``: wall time per pair and its ratio to AlignMTB's on the same pairs.

After each real bracket, the SIFT homography's own spread at the corners (pairs with 500+
inliers): a least-squares homography re-fitted to its inliers resampled with replacement (RMS
corner movement over 200 draws: the statistical spread), the corner distance between the
least-squares fit of all its inliers and MAGSAC++'s (the same matches, another estimator: where
the scene is not one plane each picks its own compromise), and ours to both.

Cases:

1. ``sim``: simulated hand-held pairs rendered here from the project's procedural scenes
   (``hdrcore.synthetic.make_scene``, green radiance): each frame integrates the continuous
   scene over its pixels (the simulator's "area" rendering) at positions moved by a known map,
   then is exposed (times 1 and 4, linear response, Gaussian noise of 1 level, 8 and 12 bits).
   The bright frame moves by ``similarity`` (scale 0.99-1.01, rotation +-1 deg, shift +-15 px
   about the centre), ``homography`` (that and a perspective tilt moving the corners by up to
   about 1 % of the half diagonal) or ``two planes`` (a similarity background and a foreground
   plane, the same kind of scene at another brightness, over about a tenth of the frame with
   2-6 px more parallax; the corner error is the background's). Saturation 0.97, noise floor
   5 levels (5 sigma). The simulator itself has no scale, perspective or second plane.
2. ``moved``: the real tripod frames of ``../shared/data/frobisher-colour-hdri`` (response
   recovered by ``hdrcore.response``), the brighter frame of each pair moved by a known
   similarity or homography (cubic spline, 40 px border cropped).
3. ``real``: the hand-held phone brackets ``handheld-xperia-library`` (rolls up to 0.24 deg)
   and ``handheld-pixel7-lab`` (vertical shifts up to 19 px), consecutive pairs by brightness,
   green channel linearised with the response and ratios the pipeline recovers
   (``Pipeline.run(until="ratios")``), registered at full resolution through the level table.
4. ``speed``: a 24-megapixel pair (the pipeline bench's bracket, cached under ``bench/out/``):
   best of 3 per method, ratio to AlignMTB, and the residual measurement's own time.

``--quick``: 2 pairs per simulated case, 12-bit only, 4 moved pairs, the Pixel 7 bracket only,
no 24-megapixel timing. Numbers measured on a shared 2-core machine while other people use it
are pessimistic.
"""

from __future__ import annotations

import argparse
import inspect
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hdrcore.registration import MODELS, corner_error, register_pair  # noqa: E402
from hdrcore.registration.residual import residual_motion  # noqa: E402
from hdrcore.synthetic import make_scene  # noqa: E402

DATA = (ROOT / ".." / "shared" / "data").resolve()
SCENES = ("window", "landscape", "night", "patches")
SIFT_MIN_INLIERS = 500


# ------------------------------------------------------------------------------------ a pair
@dataclass
class Pair:
    """One consecutive pair as every method sees it.

    ``dark`` / ``bright``: linear float frames, or integer levels read through ``lut``;
    ``gamma`` (optional): the 8-bit gamma-encoded frames for AlignMTB (else made from linear);
    ``truth``: the 3x3 pair matrix (bright -> dark) of the dominant plane, when known.
    """

    name: str
    dark: np.ndarray
    bright: np.ndarray
    ratio: float
    saturation: float
    noise_floor: float
    lut: np.ndarray | None = None
    truth: np.ndarray | None = None
    gamma: tuple[np.ndarray, np.ndarray] | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return self.dark.shape

    def linear(self) -> tuple[np.ndarray, np.ndarray]:
        if "linear" not in self._cache:
            if self.lut is None:
                self._cache["linear"] = (
                    np.asarray(self.dark, np.float32),
                    np.asarray(self.bright, np.float32),
                )
            else:
                self._cache["linear"] = (self.lut[self.dark], self.lut[self.bright])
        return self._cache["linear"]

    def gamma8(self) -> tuple[np.ndarray, np.ndarray]:
        if self.gamma is not None:
            return self.gamma
        if "gamma" not in self._cache:
            d, b = self.linear()
            self._cache["gamma"] = (_gamma8(d / self.saturation), _gamma8(b / self.saturation))
        return self._cache["gamma"]

    def equalised8(self) -> tuple[np.ndarray, np.ndarray]:
        if "eq" not in self._cache:
            d, b = self.linear()
            lo, hi = self.noise_floor * self.ratio, self.saturation

            def tone(v: np.ndarray) -> np.ndarray:
                t = (np.log(np.clip(v, lo, hi)) - np.log(lo)) / (np.log(hi) - np.log(lo))
                return (t * 255 + 0.5).astype(np.uint8)

            self._cache["eq"] = (tone(d * np.float32(self.ratio)), tone(b))
        return self._cache["eq"]


def _gamma8(x: np.ndarray) -> np.ndarray:
    return (np.clip(x, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)


def _h(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, float)
    return np.vstack([m, [0.0, 0.0, 1.0]]) if m.shape == (2, 3) else m / m[2, 2]


def _block_mean(img: np.ndarray, f: int) -> np.ndarray:
    if f == 1:
        return img
    h, w = img.shape[0] // f * f, img.shape[1] // f * f
    return cv2.resize(img[:h, :w], (w // f, h // f), interpolation=cv2.INTER_AREA)


def _rescale(m: np.ndarray, f: float) -> np.ndarray:
    """A pair matrix found on frames block-mean reduced by ``f`` as a full-resolution matrix
    (a reduced pixel centre ``x`` sits at ``f x + (f - 1) / 2``)."""
    s = np.array([[f, 0, (f - 1) / 2], [0, f, (f - 1) / 2], [0, 0, 1.0]])
    return s @ _h(m) @ np.linalg.inv(s)


# ---------------------------------------------------------------------------------- methods
@dataclass
class Estimate:
    matrix: np.ndarray | None  # 3x3 bright -> dark, None: failed
    ok: bool
    note: str = ""
    inliers: int = -1
    field: object = None  # a displacement field on the dark frame's grid (ours + field)


def ours(model: str, check: bool = True) -> Callable[[Pair], Estimate]:
    """Our registration; with ``check`` (the accuracy tables) the pair's status includes the
    independent residual check (``check_residual=True``: ``weak`` when the residual is not
    aligned, its motion still used); the speed table times the search alone."""

    def run(p: Pair) -> Estimate:
        kw = {"lut": p.lut} if p.lut is not None else {}
        r = register_pair(
            p.dark,
            p.bright,
            p.ratio,
            saturation=p.saturation,
            noise_floor=p.noise_floor,
            model=model,
            previews=False,
            check_residual=check,
            **kw,
        )
        h = getattr(r, "homography", None)
        h = _h(r.matrix) if h is None else _h(h)
        return Estimate(h if r.usable else None, r.ok, f"{r.status}: {r.message}")

    return run


def ours_with_field(model: str) -> Callable[[Pair], Estimate]:
    """Ours with its local refinement (what the pipeline warps with): the pair registered as
    by :func:`ours`, then :func:`hdrcore.registration.local.refine_bracket` on the two frames
    (the dark one the reference); the field is used where the refinement keeps it (the
    pipeline's ``--local auto`` when the check calls the pair misaligned). Real pairs only: the
    corner error of a field is not defined."""
    from hdrcore.registration.local import refine_bracket

    search = ours(model)

    def run(p: Pair) -> Estimate:
        e = search(p)
        if e.matrix is None or p.truth is not None:
            return e
        loc = refine_bracket(
            [p.dark, p.bright],
            [1.0, p.ratio],
            [np.eye(3), e.matrix],
            0,
            saturation=p.saturation,
            noise_floor=p.noise_floor,
            lut=p.lut,
        )
        fr = loc.frames[0]
        if not fr.kept:
            return e
        return Estimate(e.matrix, e.ok, e.note + "; field kept", field=fr.candidate)

    return run


def peer_mtb(p: Pair) -> Estimate:
    d8, b8 = p.gamma8()
    sx, sy = cv2.createAlignMTB().calculateShift(d8, b8)
    # calculateShift(img0, img1): shifting img1 by (sx, sy) aligns it to img0, i.e.
    # bright(x - s) = dark(x): the pair matrix (bright -> dark) is a translation by +s.
    return Estimate(np.array([[1, 0, sx], [0, 1, sy], [0, 0, 1.0]]), True)


def peer_ecc(motion: int) -> Callable[[Pair], Estimate]:
    def run(p: Pair) -> Estimate:
        d8, b8 = p.equalised8()
        h, w = p.shape
        finest = 1
        while h * w / finest**2 > 1.5e6:
            finest *= 2
        coarsest = finest
        while h * w / coarsest**2 > 1.2e5 and min(h, w) // (2 * coarsest) >= 64:
            coarsest *= 2
        warp = np.eye(3)
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
        f = coarsest
        while f >= finest:
            tpl = _block_mean(b8, f).astype(np.float32)
            inp = _block_mean(d8, f).astype(np.float32)
            start = np.linalg.inv(_rescale(np.eye(3), f)) @ warp @ _rescale(np.eye(3), f)
            m = start if motion == cv2.MOTION_HOMOGRAPHY else start[:2]
            try:
                # template = bright, input = dark: dark(W x) ~ bright(x), W is the pair matrix
                _, m = cv2.findTransformECC(tpl, inp, m.astype(np.float32), motion, crit, None, 5)
            except cv2.error as exc:
                return Estimate(None, False, f"ECC failed at 1/{f}: {str(exc).splitlines()[-1]}")
            warp = _rescale(m.astype(np.float64), f)
            f //= 2
        return Estimate(warp, True)

    return run


def _sift_matches(p: Pair):
    if "sift" not in p._cache:
        t0 = time.perf_counter()
        d8, b8 = p.equalised8()
        f = 1  # full resolution (see the docstring)
        d8, b8 = _block_mean(d8, f), _block_mean(b8, f)
        sift = cv2.SIFT_create()
        kb, db = sift.detectAndCompute(b8, None)
        kd, dd = sift.detectAndCompute(d8, None)
        pb = pd = None
        if db is not None and dd is not None and len(kb) >= 4 and len(kd) >= 4:
            matches = cv2.BFMatcher().knnMatch(db, dd, k=2)
            good = [
                m for m, n in (q for q in matches if len(q) == 2) if m.distance < 0.75 * n.distance
            ]
            if len(good) >= 4:
                # keypoints at full resolution (a reduced pixel centre x is at f x + (f-1)/2)
                pb = np.float32([kb[m.queryIdx].pt for m in good]) * f + (f - 1) / 2
                pd = np.float32([kd[m.trainIdx].pt for m in good]) * f + (f - 1) / 2
        p._cache["sift"] = (pb, pd, f, time.perf_counter() - t0)
    return p._cache["sift"]


def peer_sift(homography: bool) -> Callable[[Pair], Estimate]:
    def run(p: Pair) -> Estimate:
        pb, pd, f, _ = _sift_matches(p)
        if pb is None:
            return Estimate(None, False, "too few SIFT matches", 0)
        if homography:
            m, inl = cv2.findHomography(pb, pd, cv2.USAC_MAGSAC, 1.0 * f)
            if m is not None:
                keep = inl.ravel().astype(bool)
                p._cache["sift_h_inliers"] = (pb[keep], pd[keep])
        else:
            m, inl = cv2.estimateAffinePartial2D(
                pb, pd, method=cv2.RANSAC, ransacReprojThreshold=1.0 * f
            )
        if m is None:
            return Estimate(None, False, "RANSAC found no model", 0)
        return Estimate(_h(m), True, "", int(inl.sum()))

    return run


def methods() -> dict[str, Callable[[Pair], Estimate]]:
    out: dict[str, Callable[[Pair], Estimate]] = {f"ours {m}": ours(m) for m in MODELS}
    out.update(
        {
            "AlignMTB": peer_mtb,
            "ECC euclidean": peer_ecc(cv2.MOTION_EUCLIDEAN),
            "ECC homography": peer_ecc(cv2.MOTION_HOMOGRAPHY),
            "SIFT+RANSAC similarity": peer_sift(False),
            "SIFT+RANSAC homography": peer_sift(True),
        }
    )
    return out


# -------------------------------------------------------------------------------- measuring
@dataclass
class Row:
    """One method over a set of pairs."""

    corner: list[float] = field(default_factory=list)  # mean corner error per pair
    worst: list[float] = field(default_factory=list)  # max corner error per pair
    residual: list[float] = field(default_factory=list)  # per pair (NaN: failed/unmeasured)
    to_sift: list[float] = field(default_factory=list)
    reproj: list[float] = field(default_factory=list)  # SIFT-H's inlier matches, median px
    seconds: list[float] = field(default_factory=list)
    fails: int = 0
    ok_but_off: int = 0
    notes: list[str] = field(default_factory=list)
    statuses: list[str] = field(default_factory=list)


def residual_of(p: Pair, matrix: np.ndarray | None, fld=None):
    if matrix is None:
        return None
    kw = {"lut": p.lut} if p.lut is not None else {}
    if fld is not None:  # the bright frame read through H and the field onto the dark grid
        from bench_local import _warp  # the same cubic-spline read through H and a field

        lin = p.lut[p.bright] if p.lut is not None else p.bright
        b = _warp(np.asarray(lin, np.float32), np.linalg.inv(matrix), fld)
        d = p.lut[p.dark] if p.lut is not None else p.dark
        return residual_motion(
            np.asarray(d, np.float32),
            b.astype(np.float32),
            p.ratio,
            None,
            saturation=p.saturation,
            noise_floor=p.noise_floor,
        )
    return residual_motion(
        p.dark, p.bright, p.ratio, matrix, saturation=p.saturation, noise_floor=p.noise_floor, **kw
    )


def measure(
    pairs: Sequence[Pair], meths: dict[str, Callable[[Pair], Estimate]]
) -> tuple[dict[str, Row], list[dict]]:
    """Every method on every pair; per-pair details for the per-pair tables."""
    rows = {name: Row() for name in ["none", *meths]}
    details = []
    for p in pairs:
        est: dict[str, Estimate] = {"none": Estimate(np.eye(3), True)}
        secs: dict[str, float] = {"none": 0.0}
        for name, fn in meths.items():
            detect = _sift_matches(p)[3] if name.startswith("SIFT") else 0.0  # shared keypoints
            t0 = time.perf_counter()
            est[name] = fn(p)
            secs[name] = time.perf_counter() - t0 + detect
        sift_h = est.get("SIFT+RANSAC homography")
        det = {"pair": p.name, "estimates": est, "residual": {}}
        for name, e in est.items():
            row = rows[name]
            row.seconds.append(secs[name])
            res = residual_of(p, e.matrix, e.field)
            r = np.nan if res is None or res.status == "unmeasured" else res.median
            row.residual.append(r)
            det["residual"][name] = res
            if e.matrix is None:
                row.fails += 1
                row.notes.append(e.note)
                continue
            if name.startswith("ours") and e.ok and np.isfinite(r) and r > 1.0:
                row.ok_but_off += 1
            if p.truth is not None:
                c = corner_error(e.matrix, p.truth, p.shape)
                row.corner.append(float(c.mean()))
                row.worst.append(float(c.max()))
            if (
                sift_h is not None
                and sift_h.matrix is not None
                and sift_h.inliers >= SIFT_MIN_INLIERS
            ):
                row.to_sift.append(float(corner_error(e.matrix, sift_h.matrix, p.shape).mean()))
                pb, pd = p._cache["sift_h_inliers"]
                q = np.c_[pb, np.ones(len(pb))] @ e.matrix.T
                row.reproj.append(float(np.median(np.hypot(*(q[:, :2] / q[:, 2:] - pd).T))))
        details.append(det)
    return rows, details


def _f(values: Sequence[float], fn, digits: int = 3) -> str:
    v = np.asarray([x for x in values if np.isfinite(x)], float)
    return "-" if v.size == 0 else f"{fn(v):.{digits}f}"


def print_summary(rows: dict[str, Row], n: int, *, truth: bool, sift: bool) -> None:
    mtb = float(np.sum(rows["AlignMTB"].seconds)) if "AlignMTB" in rows else np.nan
    cols = ["method", "failed"]
    if truth:
        cols += ["mean corner px", "worst corner px"]
    cols += [
        "residual px (median pair)",
        "residual px (worst pair)",
        "residual unmeasured",
        "ok, res > 1 px",
    ]
    if sift:
        cols += [
            f"to SIFT-H px (SIFT >= {SIFT_MIN_INLIERS} inliers)",
            "SIFT-H inliers reprojected px",
        ]
    cols += ["s/pair", "x MTB"]
    print("\n| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for name, r in rows.items():
        cells = [name, f"{r.fails}/{n}"]
        if truth:
            cells += [_f(r.corner, np.mean), _f(r.worst, np.max)]
        unmeasured = int(np.isnan(r.residual).sum()) - r.fails
        cells += [
            _f(r.residual, np.median),
            _f(r.residual, np.max),
            f"{unmeasured}",
            f"{r.ok_but_off}" if name.startswith("ours") else "",
        ]
        if sift:
            cells += [_f(r.to_sift, np.mean) + f" ({len(r.to_sift)})", _f(r.reproj, np.mean)]
        secs = float(np.sum(r.seconds))
        cells += [
            "" if name == "none" else f"{secs / n:.3f}",
            "" if name == "none" or not mtb else f"{secs / mtb:.1f}",
        ]
        print("| " + " | ".join(cells) + " |")


def print_reference_spread(pairs: Sequence[Pair], details: list[dict], seed: int = 0) -> None:
    """How well the SIFT homography itself is determined at the corners, per pair with 500+
    inliers: the RMS corner movement of a least-squares homography re-fitted to its inliers
    resampled with replacement (200 draws: the statistical spread), the corner distance between
    that least-squares fit of all its inliers and MAGSAC++'s own (the same matches, another
    estimator: a plane's choice where the scene is not one plane), and ours to both."""
    rng = np.random.default_rng(seed)
    print(
        "\n| pair | SIFT-H inliers | bootstrap corner RMS px | least squares to MAGSAC px "
        "| ours H to MAGSAC px | ours H to least squares px |"
    )
    print("|---|---|---|---|---|---|")
    for p, det in zip(pairs, details, strict=True):
        sift_h = det["estimates"].get("SIFT+RANSAC homography")
        ours_h = det["estimates"].get("ours homography")
        if (
            sift_h is None
            or sift_h.matrix is None
            or sift_h.inliers < SIFT_MIN_INLIERS
            or "sift_h_inliers" not in p._cache
        ):
            continue
        pb, pd = p._cache["sift_h_inliers"]
        h_ls, _ = cv2.findHomography(pb, pd, 0)
        draws = []
        for _ in range(200):
            idx = rng.integers(0, len(pb), len(pb))
            h_b, _ = cv2.findHomography(pb[idx], pd[idx], 0)
            if h_b is not None:
                draws.append(corner_error(h_b, h_ls, p.shape))
        rms = float(np.sqrt(np.mean(np.square(draws)))) if draws else np.nan
        ours = (
            (
                f"{corner_error(ours_h.matrix, sift_h.matrix, p.shape).mean():.3f}",
                f"{corner_error(ours_h.matrix, h_ls, p.shape).mean():.3f}",
            )
            if ours_h is not None and ours_h.matrix is not None
            else ("-", "-")
        )
        print(
            f"| {p.name} | {sift_h.inliers} | {rms:.3f} | "
            f"{corner_error(h_ls, sift_h.matrix, p.shape).mean():.3f} | {ours[0]} | {ours[1]} |"
        )


def print_pairs(details: list[dict], names: Sequence[str]) -> None:
    """Per pair: SIFT inliers, the residual of each method, and for ours with the default
    model its status and the residual's sentence."""
    default = inspect.signature(register_pair).parameters["model"].default
    first = (
        f"ours {default}"
        if f"ours {default}" in names
        else next(n for n in names if n.startswith("ours"))
    )
    print(
        "\n| pair | SIFT inliers sim/H | "
        + " | ".join(names)
        + f" | {first}: status / residual says |"
    )
    print("|" + "---|" * (len(names) + 3))
    for det in details:
        est, res = det["estimates"], det["residual"]
        inl = "/".join(
            str(est[k].inliers)
            for k in ("SIFT+RANSAC similarity", "SIFT+RANSAC homography")
            if k in est
        )
        cells = []
        for n in names:
            r = res.get(n)
            cells.append(
                "fail" if r is None else ("-" if r.status == "unmeasured" else f"{r.median:.2f}")
            )
        r0 = res.get(first)
        say = est[first].note.split(":")[0] + " / " + ("-" if r0 is None else r0.describe())
        print(f"| {det['pair']} | {inl} | " + " | ".join(cells) + f" | {say} |")


# ------------------------------------------------------------------------ simulated pairs
def _render(big: np.ndarray, h: np.ndarray, shape: tuple[int, int], margin: int) -> np.ndarray:
    """The continuous scene (bilinear interpolant of ``big``) integrated over each pixel ``p``
    of a frame that looks at ``h p`` (the simulator's "area" rendering, quadratic B-spline)."""
    hh, ww = shape
    yy, xx = np.mgrid[0:hh, 0:ww].astype(np.float64)
    zw = h[2, 0] * xx + h[2, 1] * yy + h[2, 2]
    xs = (h[0, 0] * xx + h[0, 1] * yy + h[0, 2]) / zw + margin
    ys = (h[1, 0] * xx + h[1, 1] * yy + h[1, 2]) / zw + margin
    return ndimage.map_coordinates(big, [ys, xs], order=2, mode="nearest", prefilter=False)


def similarity3(shape, dx, dy, angle_deg, scale) -> np.ndarray:
    h, w = shape
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    t = np.radians(angle_deg)
    a = scale * np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    m = np.eye(3)
    m[:2, :2] = a
    m[:2, 2] = c - a @ c + np.array([dx, dy])
    return m


def tilt3(shape, gx, gy) -> np.ndarray:
    """A perspective tilt about the image centre: the corners move by about ``(gx, gy)`` times
    the half diagonal (relative)."""
    h, w = shape
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    r = 0.5 * np.hypot(w - 1, h - 1)
    p = np.eye(3)
    p[2, 0], p[2, 1] = gx / r, gy / r
    t, ti = np.eye(3), np.eye(3)
    t[:2, 2], ti[:2, 2] = c, -c
    return t @ p @ ti


def simulated_pair(kind: str, bits: int, seed: int, shape: tuple[int, int]) -> Pair:
    rng = np.random.default_rng(1000 * bits + seed)
    h, w = shape
    margin = 48
    scene = SCENES[seed % len(SCENES)]
    big = make_scene(scene, (h + 2 * margin, w + 2 * margin), seed)[..., 1].astype(np.float64)
    motion = similarity3(
        shape, *rng.uniform(-15, 15, 2), rng.uniform(-1, 1), rng.uniform(0.99, 1.01)
    )
    if kind == "homography":
        motion = motion @ tilt3(shape, *rng.uniform(-0.01, 0.01, 2))
    dark = _render(big, np.eye(3), shape, margin)
    bright = _render(big, motion, shape, margin)
    if kind == "two planes":
        # A foreground plane (the same kind of scene, another seed and brightness) over about
        # a tenth of the frame, with 2-6 px more parallax than the background in the bright
        # frame.
        fg = make_scene(scene, big.shape, seed + 99)[..., 1].astype(np.float64)
        fg *= float(rng.uniform(0.5, 2.0))
        yy, xx = np.mgrid[0 : big.shape[0], 0 : big.shape[1]].astype(np.float64)
        cx, cy = rng.uniform(0.25, 0.75) * w + margin, rng.uniform(0.3, 0.7) * h + margin
        ax, ay = 0.18 * w, 0.16 * h
        alpha = np.clip(
            1.5 - 1.5 * np.maximum(np.abs(xx - cx) / ax, np.abs(yy - cy) / ay) ** 4, 0, 1
        )
        ang = rng.uniform(0, 2 * np.pi)
        par = rng.uniform(2, 6) * np.array([np.cos(ang), np.sin(ang)])
        near = np.eye(3)
        near[:2, 2] = par
        near = near @ motion
        a_d = _render(alpha, np.eye(3), shape, margin)
        a_b = _render(alpha, near, shape, margin)
        dark = a_d * _render(fg, np.eye(3), shape, margin) + (1 - a_d) * dark
        bright = a_b * _render(fg, near, shape, margin) + (1 - a_b) * bright
    ratio = 4.0
    key = 0.18 / float(np.median(dark)) / np.sqrt(ratio)
    ml = (1 << bits) - 1
    noise = np.random.default_rng(seed + 7)

    def expose(e: np.ndarray, t: float) -> np.ndarray:
        y = np.clip(e * t * key, 0, 1) * ml + noise.standard_normal(e.shape)
        return (np.clip(np.rint(y), 0, ml) / ml).astype(np.float32)

    return Pair(
        f"{scene} {seed}",
        expose(dark, 1.0),
        expose(bright, ratio),
        ratio,
        0.97,
        5.0 / ml,
        truth=motion,
    )


def simulated(args, meths) -> None:
    kinds = ("similarity", "homography", "two planes")
    bits_list = (12,) if args.quick else (8, 12)
    n = args.pairs
    for kind in kinds:
        for bits in bits_list:
            pairs = [simulated_pair(kind, bits, s, tuple(args.shape)) for s in range(n)]
            rows, _ = measure(pairs, meths)
            print(
                f"\n### Simulated {kind}, {bits}-bit, {args.shape[1]}x{args.shape[0]}, "
                f"ratio 4, {n} pairs"
            )
            print_summary(rows, n, truth=True, sift=False)


# -------------------------------------------------------------------------- real + moved
def _frobisher():
    from PIL import Image

    from hdrcore.response import recover_response

    folder = DATA / "frobisher-colour-hdri"
    names = ["IMG_2600.jpg", "IMG_2601.jpg", "IMG_2602.jpg"]  # 1/8, 1, 8 s
    times = [0.125, 1.0, 8.0]
    raw = [np.asarray(Image.open(folder / n)) for n in names]
    lut = recover_response(raw, times, max_level=255).g[1].astype(np.float32)
    return [f[..., 1] for f in raw], times, lut


def _warp_spline(img: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``img`` at ``m @ p`` for every pixel ``p`` (3x3; cubic spline), NaN outside."""
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    m = _h(m)
    zw = m[2, 0] * xx + m[2, 1] * yy + m[2, 2]
    xs = (m[0, 0] * xx + m[0, 1] * yy + m[0, 2]) / zw
    ys = (m[1, 0] * xx + m[1, 1] * yy + m[1, 2]) / zw
    out = ndimage.map_coordinates(
        np.asarray(img, np.float64), [ys, xs], order=3, mode="nearest"
    ).astype(np.float32)
    out[~((xs >= 0) & (xs <= w - 1) & (ys >= 0) & (ys <= h - 1))] = np.nan
    return out


def moved(args, meths) -> None:
    if not (DATA / "frobisher-colour-hdri").is_dir():
        print("\n(moved frobisher pairs skipped: ../shared/data not found)")
        return
    levels, times, lut = _frobisher()
    linear = [lut[v] for v in levels]
    h, w = levels[0].shape
    b = 40
    crop = (slice(b, h - b), slice(b, w - b))
    sims = [
        (7.3, -4.6, 0.6, 1.006),
        (-12.8, 9.1, -0.9, 0.993),
        (3.4, 15.2, 0.3, 1.009),
        (-18.5, -6.7, 1.0, 0.991),
    ]
    tilts = [(0.006, -0.004), (-0.008, 0.005), (0.004, 0.009), (-0.009, -0.006)]
    motions = [("similarity", similarity3((h, w), *s), s) for s in sims]
    motions += [
        ("homography", similarity3((h, w), *s) @ tilt3((h, w), *t), s + t)
        for s, t in zip(sims, tilts, strict=True)
    ]
    if args.quick:
        motions = motions[::2][:4]
    shift, back = np.eye(3), np.eye(3)
    shift[:2, 2], back[:2, 2] = b, -b
    pairs = []
    for i in range(2):
        k = times[i + 1] / times[i]
        for kind, t_full, par in motions:
            # bright(x) = original_bright(T x): the pair matrix (bright -> dark) is T.
            moved_b = np.nan_to_num(_warp_spline(linear[i + 1], t_full)[crop], nan=0.0)
            truth = back @ t_full @ shift  # in the crop's coordinates
            gamma = (
                levels[i][crop].copy(),
                np.clip(
                    np.rint(_warp_spline(levels[i + 1].astype(np.float32), t_full)[crop]), 0, 255
                ).astype(np.uint8),
            )
            pairs.append(
                Pair(
                    f"{i}-{i + 1} {kind} {np.round(par, 3).tolist()}",
                    linear[i][crop].copy(),
                    moved_b.astype(np.float32),
                    k,
                    float(lut[247]),
                    float(lut[5]),
                    truth=truth,
                    gamma=gamma,
                )
            )
    rows, details = measure(pairs, meths)
    print(
        f"\n## Real frobisher frames ({w}x{h} JPEG, tripod, ratio 8) moved by a known "
        f"similarity / homography ({len(pairs)} pairs, a {b} px border cropped)"
    )
    print_summary(rows, len(pairs), truth=True, sift=True)
    print_pairs(details, list(rows))


def _load_real(name: str):
    from hdrcore.io import load_bracket
    from hdrcore.pipeline import Pipeline, PipelineParams

    d = DATA / name
    files = sorted(p for p in d.iterdir() if p.suffix.lower() in (".jpg", ".jpeg"))
    b = load_bracket(files)
    r = Pipeline(b).run(PipelineParams(align="none", registration_previews=False), until="ratios")
    m = b.max_level
    lut = np.arange(m + 1, dtype=np.float32) / m if r.lut is None else r.lut[1].astype(np.float32)
    sat = float(np.interp(r.saturation, np.arange(m + 1), lut))
    nf = float(np.interp(r.noise_floor, np.arange(m + 1), lut))
    ratios = [float(x) for x in r.exposures.starting_ratios()]
    names = [Path(f.path).name for f in b.frames]
    return b, lut, sat, nf, ratios, names


def real(args, meths) -> None:
    sets = (
        ["handheld-pixel7-lab"]
        if args.quick
        else ["handheld-xperia-library", "handheld-pixel7-lab"]
    )
    for name in sets:
        if not (DATA / name).is_dir():
            print(f"\n({name} skipped: not found)")
            continue
        b, lut, sat, nf, ratios, names = _load_real(name)
        pairs = []
        for i in range(len(b.frames) - 1):
            d = b.frames[i].levels[..., 1]
            g = b.frames[i + 1].levels[..., 1]
            pairs.append(
                Pair(
                    f"{names[i]} -> {names[i + 1]}",
                    d,
                    g,
                    ratios[i],
                    sat,
                    nf,
                    lut=lut,
                    gamma=(np.ascontiguousarray(d), np.ascontiguousarray(g)),
                )
            )
        real_meths = dict(meths)
        if "ours homography" in meths:  # what the pipeline warps with: the motion and a field
            real_meths = {}
            for k, fn in meths.items():
                real_meths[k] = fn
                if k == "ours homography":
                    real_meths["ours homography + field"] = ours_with_field("homography")
        rows, details = measure(pairs, real_meths)
        h, w = b.shape
        print(
            f"\n## Real hand-held bracket {name} ({w}x{h} JPEG, {len(pairs)} consecutive "
            f"pairs, ratios {', '.join(f'{r:.2f}' for r in ratios)})"
        )
        print_summary(rows, len(pairs), truth=False, sift=True)
        print_pairs(details, list(rows))
        print(
            "\nThe SIFT homography as a reference (pairs with "
            f"{SIFT_MIN_INLIERS}+ inliers): its own spread at the corners"
        )
        print_reference_spread(pairs, details)
        sim = rows["SIFT+RANSAC similarity"].residual
        for mname, row in rows.items():
            if not mname.startswith("ours"):
                continue
            worse = [
                det["pair"]
                for det, r, s in zip(details, row.residual, sim, strict=True)
                if not (np.isfinite(r) and r <= max(0.3, s if np.isfinite(s) else 0.3))
            ]
            print(
                f"\n{mname}: pairs with a residual above max(0.3 px, SIFT similarity's): "
                f"{len(worse)}/{len(pairs)}" + (f" ({'; '.join(worse)})" if worse else "")
            )


# ---------------------------------------------------------------------------------- speed
def speed(args, meths) -> None:
    import json

    sys.path.insert(0, str(ROOT / "bench"))
    from bench_pipeline import make_bracket

    from hdrcore.io import load_bracket

    d = make_bracket((4000, 6000), 3)
    b = load_bracket([d])
    truth = json.loads((d / "truth.json").read_text())
    ml = b.max_level
    lut = np.arange(ml + 1, dtype=np.float32) / ml
    views = [f.levels[..., 1] for f in b.frames]
    # noise floor: 5 sigma of the bracket's read noise (2 levels)
    pair = Pair(
        "24 MP 0-1",
        views[0],
        views[1],
        float(truth["ratios"][0]),
        0.97,
        10.0 / ml,
        lut=lut,
        truth=_h(np.array(truth["pairs"][0]["matrix"])),
    )
    print(
        f"\n## Speed: one 24-megapixel pair (6000x4000, the pipeline bench's bracket), best of "
        f"3, same run; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores"
    )
    print("\n| method | best s | x MTB | worst corner px | residual px |")
    print("|---|---|---|---|---|")
    best: dict[str, float] = {}
    out: dict[str, Estimate] = {}
    meths = {
        n: (ours(n.split()[1], check=False) if n.startswith("ours") else f)
        for n, f in meths.items()
    }  # the search alone; the residual check is timed below
    order = ["AlignMTB"] + [m for m in meths if m != "AlignMTB"]
    for name in order:
        if name.startswith("ECC") or name.startswith("SIFT"):
            continue  # seconds to minutes at 24 MP; their accuracy is in the other tables
        times_ = []
        pair.gamma8()  # AlignMTB's 8-bit input is made outside its timing
        for _ in range(3):
            t0 = time.perf_counter()
            out[name] = meths[name](pair)
            times_.append(time.perf_counter() - t0)
        best[name] = min(times_)
    for name, t in best.items():
        e = out[name]
        res = residual_of(pair, e.matrix)
        c = (
            "-"
            if e.matrix is None
            else f"{corner_error(e.matrix, pair.truth, pair.shape).max():.3f}"
        )
        r = "-" if res is None or res.status == "unmeasured" else f"{res.median:.3f}"
        print(f"| {name} | {t:.3f} | {t / best['AlignMTB']:.2f} | {c} | {r} |")
    default = inspect.signature(register_pair).parameters["model"].default
    first = (
        f"ours {default}"
        if f"ours {default}" in best
        else next(n for n in best if n.startswith("ours"))
    )
    ts = []
    for _ in range(3):
        t0 = time.perf_counter()
        res = residual_of(pair, out[first].matrix)
        ts.append(time.perf_counter() - t0)
    print(
        f"\nresidual_motion on the aligned pair ({first}): best {min(ts):.3f} s "
        f"(level {res.level}, {res.valid.size} tiles of {res.tile} px, {res.n_valid} "
        f"confident): {res.describe()}"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="a small subset (see the docstring)")
    p.add_argument(
        "--only",
        default="sim,moved,real,speed",
        help="comma-separated parts: sim, moved, real, speed",
    )
    p.add_argument("--pairs", type=int, default=None, help="simulated pairs per case")
    p.add_argument("--shape", type=int, nargs=2, default=(384, 576))
    args = p.parse_args()
    if args.pairs is None:
        args.pairs = 2 if args.quick else 6
    parts = set(args.only.split(","))
    meths = methods()
    print(
        f"# Registration bench (models {', '.join(MODELS)}; load average "
        f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; shared machine: timings are "
        f"pessimistic)"
    )
    if "sim" in parts:
        simulated(args, meths)
    if "moved" in parts:
        moved(args, meths)
    if "real" in parts:
        real(args, meths)
    if "speed" in parts and not args.quick:
        speed(args, meths)


if __name__ == "__main__":
    main()
