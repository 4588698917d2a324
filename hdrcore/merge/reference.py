"""The numpy reference engine of the merge (``engine="numpy"``): one vectorised operation at a
time over chunks of rows, channel-planar scratch buffers, float32 throughout, in the order the
fused kernel (:mod:`hdrcore.merge._fused`) repeats to the last bit. It runs the inputs the fused
kernel does not take (1 or 4 channels: the RAW mosaic merge) and ``engine="numpy"``.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..geometry import keys_weights
from .maps import to_float16_nonnegative
from .plan import Outputs, Plan, sample_model
from .weights import WEIGHTS

__all__ = ["LUT_MODE", "ReferenceKernel", "Scratch", "run_reference"]


def _bilinear_weights(f: np.ndarray) -> np.ndarray:
    return np.stack([1.0 - f, f])


LUT_MODE = "levels"
"""How resampled frames with a response LUT are linearised: ``"levels"`` (the default and the
fused kernel's) interpolates the levels and reads the LUT linearly between entries;
``"samples"`` (numpy reference only, kept for the accuracy comparison in
``bench/bench_merge.py``) linearises the 16 taps and interpolates linear values. On simulated
gamma brackets with the true motion "levels" is as accurate or slightly better (the scene is
smoother in the gamma domain than in linear values) and needs one table read, not 16."""


class Scratch:
    """Per-worker buffers for one chunk, channel-planar so every operation is contiguous."""

    def __init__(self, n_frames: int, size: int, channels: int) -> None:
        planes = (channels, size)
        # E_k = g(M) / dt of every frame, as the sums saw it: the fallback values
        self.ek = np.empty((n_frames, channels, size), np.float32)
        self.den = np.empty(planes, np.float32)  # sum w
        self.num = np.empty(planes, np.float32)  # sum w E_k
        self.s2 = np.empty(planes, np.float32)  # sum w E_k^2
        self.sv = np.empty(planes, np.float32)  # sum w var(E_k)
        self.x = np.empty(size, np.float32)
        self.level = np.empty(size, np.float32)
        self.var = np.empty(size, np.float32)
        self.a = np.empty(size, np.float32)
        self.b = np.empty(size, np.float32)
        self.keep = np.empty(size, bool)
        self.ok = np.empty(size, bool)
        self.flag = np.empty(size, bool)
        self.idx = np.empty(size, np.intp)
        self.i32 = np.empty(size, np.int32)
        self.nbad = np.empty(size, np.uint8)
        self.bad = np.empty((n_frames, size), bool)
        self.clip = np.empty((n_frames, size), bool)
        self.share = np.empty((n_frames, size), np.float32)


_TINY = np.float32(1e-30)


def _accumulate(op, dst: np.ndarray, src: np.ndarray) -> None:
    if op is np.copyto:
        np.copyto(dst, src)
    else:
        np.add(dst, src, out=dst)


class ReferenceKernel:
    def __init__(self, plan: Plan, out: Outputs, ghost_threshold: float, model_error: float):
        self.p = plan
        self.out = out
        m = sample_model(plan, ghost_threshold, model_error)
        self.ghost_threshold = m.ghost_threshold
        self.model_error2 = m.model_error2
        self.inv_max = m.inv_max
        self.floor_norm = m.floor_norm
        self.shot = m.shot
        self.const_var = m.const_var
        self.weight_fn = WEIGHTS[plan.weighting]
        c = plan.shape[2]
        self.lut = plan.lut if plan.lut is not None else np.zeros((c, 2), np.float32)
        self.lut_var = plan.lut_var if plan.lut_var is not None else self.lut

    # ---- linearisation of one channel of one frame's chunk ---------------------------------
    def _linearise(
        self, col: np.ndarray, ch: int, s: Scratch, m: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x, level, var)`` of a column of levels or linear values, each float32 ``(m,)``."""
        p = self.p
        level, var = s.level[:m], s.var[:m]
        if not p.integer:
            np.copyto(level, col)
            x = level
        else:
            np.multiply(col, self.inv_max, out=level, dtype=np.float32)
            if p.lut is None:
                x = level
            else:
                x, idx = s.x[:m], s.idx[:m]
                np.copyto(idx, col, casting="unsafe")
                np.take(self.lut[ch], idx, out=x)
                np.take(self.lut_var[ch], idx, out=var)
                if self.shot:
                    np.multiply(x, self.shot, out=s.a[:m])
                    var += s.a[:m]
                var += self.const_var
                return x, level, var
        np.multiply(x, self.shot, out=var)
        var += self.const_var
        return x, level, var

    # ---- resampling of a frame with a transform (reference of _fused.merge_rows) ---------
    def _sample(
        self, k: int, r0: int, r1: int
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
        """Frame ``k`` at ``T_k (x, y, 1)`` for the output pixels of rows ``r0:r1``.

        Keys cubic convolution (a = -1/2) of the raw samples (levels or linear floats) with the
        4 weights per axis shared by the channels, clamped to ``[0, max_level]`` (``[0, 1]``).
        Returns ``(values (C, m) float32, LUT values (C, m) float32 or None, tap_clip (m,),
        inside (m,))``: ``tap_clip`` where any of the 16 taps of any channel is at or above its
        saturation level, ``inside`` where the whole 4x4 support lies in the frame. With a
        response LUT the taps are linearised before the interpolation (``LUT values``).
        """
        p = self.p
        weights: Callable[[np.ndarray], np.ndarray]
        if p.resample == "cubic":
            weights, ntap, o = keys_weights, 4, 1.0  # the project's Keys weights
        else:  # bilinear: weights 1 - f, f of taps 0, 1
            weights, ntap, o = _bilinear_weights, 2, 0.0
        h, w, c = p.shape
        t = p.transforms[k]
        assert t is not None  # only resampled frames come here
        pix = np.arange(r0 * w, r1 * w, dtype=np.int64)
        yy = (pix // w).astype(np.float64)
        xx = (pix % w).astype(np.float64)
        sw = t[2, 0] * xx + t[2, 1] * yy + t[2, 2]
        sx = (t[0, 0] * xx + t[0, 1] * yy + t[0, 2]) / sw
        sy = (t[1, 0] * xx + t[1, 1] * yy + t[1, 2]) / sw
        fld = p.fields[k] if p.fields else None
        if fld is not None:  # local refinement: the field at the output pixel
            dx, dy = fld.at(xx, yy)
            sx = sx + dx
            sy = sy + dy
        fx0 = np.floor(sx)
        fy0 = np.floor(sy)
        inside = (fx0 >= o) & (fx0 <= w - (ntap - o)) & (fy0 >= o) & (fy0 <= h - (ntap - o))
        wx = weights(np.where(inside, sx - fx0, 0.0)).astype(np.float32)
        wy = weights(np.where(inside, sy - fy0, 0.0)).astype(np.float32)
        base = np.where(inside, (fy0 - o) * w + (fx0 - o), 0.0).astype(np.int64) * c
        flat = p.frames[k].reshape(-1)
        m = pix.size
        tap_clip = np.zeros(m, bool)
        vals = np.empty((c, m), np.float32)
        lut_vals = None if p.lut is None or LUT_MODE != "samples" else np.empty((c, m), np.float32)
        hi = np.float32(p.max_level if p.integer else 1.0)
        for ch in range(c):
            acc = lacc = None
            for jy in range(ntap):
                row = lrow = None
                for jx in range(ntap):
                    # (clip: an outside pixel of a frame smaller than the support reads
                    # some sample; its value and flag are discarded below)
                    taps = flat.take(base + ((jy * w + jx) * c + ch), mode="clip")
                    tap_clip |= taps >= p.saturation[ch]
                    if p.lut is not None and np.any((taps >= p.lut_len) & inside):
                        raise IndexError(f"level {int(taps.max())} past the end of the LUT")
                    term = taps.astype(np.float32) * wx[jx]
                    row = term if row is None else row + term
                    if lut_vals is not None:
                        lv = self.lut[ch].take(np.minimum(taps, p.lut_len - 1)) * wx[jx]
                        lrow = lv if lrow is None else lrow + lv
                term = row * wy[jy]
                acc = term if acc is None else acc + term
                if lut_vals is not None:
                    lv = lrow * wy[jy]
                    lacc = lv if lacc is None else lacc + lv
            assert acc is not None  # ntap >= 2 taps were summed
            np.clip(acc, np.float32(0.0), hi, out=vals[ch])
            if lut_vals is not None:
                assert lacc is not None
                np.clip(lacc, np.float32(0.0), self.lut[ch, -1], out=lut_vals[ch])
        tap_clip &= inside
        vals[:, ~inside] = 0.0  # no data (a pixel with no valid frame at all reads 0 there)
        if lut_vals is not None:
            lut_vals[:, ~inside] = 0.0
        return vals, lut_vals, tap_clip, inside

    def _linearise_sampled(
        self, vals: np.ndarray, lut_vals: np.ndarray | None, ch: int, s: Scratch, m: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x, level, var)`` of interpolated values (see :meth:`_sample`), float32 ``(m,)``.

        With a LUT, ``x`` is the interpolation of the linearised taps and the variance that of
        the LUT's level noise at the interpolated level (linear between table entries).
        """
        p = self.p
        level, var = s.level[:m], s.var[:m]
        if not p.integer:
            np.copyto(level, vals)
            x = level
        else:
            np.multiply(vals, self.inv_max, out=level)
            if p.lut is None:
                x = level
            else:
                x = s.x[:m]
                lo = np.minimum(vals.astype(np.intp), p.lut_len - 2)
                frac = vals - lo.astype(np.float32)
                if lut_vals is not None:
                    np.copyto(x, lut_vals)
                else:  # LUT_MODE "levels": the LUT linearly interpolated at the level
                    v0 = self.lut[ch].take(lo)
                    np.subtract(self.lut[ch].take(lo + 1), v0, out=x)
                    x *= frac
                    x += v0
                v0 = self.lut_var[ch].take(lo)
                np.subtract(self.lut_var[ch].take(lo + 1), v0, out=var)
                var *= frac
                var += v0
                if self.shot:
                    np.multiply(x, self.shot, out=s.a[:m])
                    var += s.a[:m]
                var += self.const_var
                return x, level, var
        np.multiply(x, self.shot, out=var)
        var += self.const_var
        return x, level, var

    # ---- one chunk of rows -------------------------------------------------------------------
    def run(self, r0: int, r1: int, s: Scratch) -> None:
        p = self.p
        _, w, c = p.shape
        m = (r1 - r0) * w
        den, num, s2, sv = s.den[:, :m], s.num[:, :m], s.s2[:, :m], s.sv[:, :m]
        keep, ok, flag = s.keep[:m], s.ok[:m], s.flag[:m]
        nbad = s.nbad[:m]
        nbad.fill(0)
        clip_count = self.out.clip_count[r0:r1].reshape(m)
        clip_count.fill(0)
        for j, k in enumerate(p.order):
            bad, clip = s.bad[k, :m], s.clip[k, :m]
            mask = p.masks[k]
            valid = None if mask is None else mask[r0:r1].reshape(m)
            if p.transforms[k] is None:
                src = p.frames[k][r0:r1].reshape(m, c)
                sampled = None
                # A pixel is clipped in this frame when any channel reaches its saturation level.
                np.greater_equal(src[:, 0], p.saturation[0], out=clip)
                for ch in range(1, c):
                    np.greater_equal(src[:, ch], p.saturation[ch], out=flag)
                    clip |= flag
            else:
                # Resampled at the mapped position: clipped when any tap of the 4x4 support in
                # any channel is; no data where the support leaves the frame.
                sampled, lut_vals, tap_clip, inside = self._sample(k, r0, r1)
                np.copyto(clip, tap_clip)
                valid = inside if valid is None else valid & inside
            if valid is not None:
                clip &= valid
                np.logical_not(valid, out=bad)
                bad |= clip
            else:
                np.copyto(bad, clip)
            clip_count += clip
            nbad += bad
            np.logical_not(bad, out=ok)
            t = float(p.times[k])
            inv_t = np.float32(1.0 / t)
            inv_t2 = np.float32(1.0 / (t * t))
            share = s.share[k, :m]
            for ch in range(c):
                if sampled is None:
                    x, level, var = self._linearise(src[:, ch], ch, s, m)
                else:
                    x, level, var = self._linearise_sampled(
                        sampled[ch], None if lut_vals is None else lut_vals[ch], ch, s, m
                    )
                e = s.ek[k, ch, :m]
                np.multiply(x, inv_t, out=e)  # E_k = g(M) / dt
                wk = self.weight_fn(level, x, t, var)
                # zero weight at or below the noise floor (this channel) and for dropped pixels
                # (all channels: any channel clipped, or invalid after the warp)
                np.greater(level, self.floor_norm, out=keep)
                keep &= ok
                wk *= keep
                # the first frame initialises the sums (saves clearing them)
                acc = np.copyto if j == 0 else np.add
                _accumulate(acc, den[ch], wk)
                _accumulate(np.copyto if ch == 0 else np.add, share, wk)
                var *= wk  # w var(E_k) = w var(x) / dt^2
                var *= inv_t2
                _accumulate(acc, sv[ch], var)
                wk *= e  # w E_k
                _accumulate(acc, num[ch], wk)
                wk *= e  # w E_k^2
                _accumulate(acc, s2[ch], wk)
        self._finish(r0, r1, s, m)

    def _finish(self, r0: int, r1: int, s: Scratch, m: int) -> None:
        p, out = self.p, self.out
        n = len(p.frames)
        c = p.shape[2]
        den, num = s.den[:, :m], s.num[:, :m]
        a, b, inv = s.a[:m], s.b[:m], s.x[:m]
        rad = out.radiance[r0:r1].reshape(m, c)
        spread, noise = s.level[:m], s.var[:m]
        wsum = out.weight_sum[r0:r1].reshape(m)
        anyzero = s.keep[:m]
        for ch in range(c):
            np.maximum(den[ch], _TINY, out=inv)
            np.divide(np.float32(1.0), inv, out=inv)
            np.multiply(num[ch], inv, out=a)  # E (0 where no weight)
            rad[:, ch] = a
            # ghost moments (maps.ghost_score_from_moments, channel-planar)
            np.multiply(s.s2[ch, :m], inv, out=b)
            np.square(a, out=a)
            b -= a
            np.maximum(b, 0.0, out=b)
            if ch == 0:
                np.copyto(spread, b)
            else:
                spread += b
            a *= self.model_error2
            np.multiply(s.sv[ch, :m], inv, out=b)
            b += a
            if ch == 0:
                np.copyto(noise, b)
                np.copyto(wsum, den[ch])
                np.less_equal(den[ch], 0.0, out=anyzero)
            else:
                noise += b
                wsum += den[ch]
                np.less_equal(den[ch], 0.0, out=s.flag[:m])
                anyzero |= s.flag[:m]
        np.maximum(noise, _TINY, out=noise)
        spread /= noise
        np.greater(spread, self.ghost_threshold, out=out.ghost[r0:r1].reshape(m))
        to_float16_nonnegative(spread, out.ghost_score[r0:r1].reshape(m), s.i32[:m])
        np.maximum(wsum, _TINY, out=inv)
        np.divide(np.float32(1.0), inv, out=inv)
        shares = s.share[:, :m]
        need = np.flatnonzero(anyzero)
        # which frames contributed to each pixel needing a fallback (before normalising)
        seen = shares[:, need] > 0.0
        shares *= inv
        clipped = out.clipped[r0:r1].reshape(m)
        under = out.underexposed[r0:r1].reshape(m)
        under.fill(False)
        clipped.fill(False)
        if need.size:
            self._fallback(need, seen, s, rad, shares, clipped, under)
        for k in range(n):
            to_float16_nonnegative(shares[k], out.shares[k, r0:r1].reshape(m), s.i32[:m])

    def _fallback(
        self,
        need: np.ndarray,
        seen: np.ndarray,
        s: Scratch,
        rad: np.ndarray,
        shares: np.ndarray,
        clipped: np.ndarray,
        under: np.ndarray,
    ) -> None:
        """Values for pixels the weighted average could not estimate (see the module doc).

        ``need``: chunk pixels with a channel of no weight; ``seen (N, q)``: frame ``k``
        contributed weight to pixel ``need[q]`` (some channel above the noise floor).
        """
        p = self.p
        order = p.order
        n = len(order)
        seen_o = seen[order]  # (N, q), exposure order
        whole = (s.den[:, need] <= 0).all(axis=0)  # no frame contributed to any channel
        clip_o = s.clip[np.ix_(order, need)]  # clipped (and valid), exposure order
        has_clip = clip_o.any(axis=0)
        first = np.where(has_clip, np.argmax(clip_o, axis=0), 0)
        usable_o = ~s.bad[np.ix_(order, need)]
        last_usable = np.where(usable_o.any(axis=0), n - 1 - np.argmax(usable_o[::-1], axis=0), -1)
        # 1) no frame gave the pixel weight, some valid frame is clipped there and every usable
        #    frame (below the floor) is a shorter exposure than the darkest clipped one: that
        #    frame's value, a lower bound (a frame too short to see the pixel, or black, says
        #    nothing against it). No valid frame at all: the darkest frame's value, not flagged.
        every = whole & ((has_clip & (last_usable < first)) | (s.nbad[need] == n))
        for j, k in enumerate(order):
            pick = need[every & (first == j)]
            if pick.size == 0:
                continue
            rad[pick] = s.ek[k][:, pick].T
            shares[:, pick] = 0.0
            shares[k, pick] = 1.0
        clipped[need[every & has_clip]] = True
        # 2) some channel at or below the noise floor in every usable frame: that channel takes
        #    the brightest usable frame that saw the pixel (any usable frame when none did; also
        #    where a longer exposure saw nothing where a shorter one clipped: the frames
        #    contradict each other, a marker or a moving object, and the longest reading stays)
        rest_q = np.flatnonzero(~every)
        if rest_q.size:
            rest = need[rest_q]
            zero = (s.den[:, rest] <= 0).T  # (q, C)
            usable = ~s.bad[np.ix_(order, rest)]
            sr = seen_o[:, rest_q]
            cand = np.where(sr.any(axis=0), sr, usable)
            last = n - 1 - np.argmax(cand[::-1], axis=0)
            for j, k in enumerate(order):
                sel = np.flatnonzero(last == j)
                if sel.size == 0:
                    continue
                pick = rest[sel]
                vals = s.ek[k][:, pick].T
                target = rad[pick]
                zc = zero[sel]
                target[zc] = vals[zc]
                rad[pick] = target
                wholes = pick[np.asarray(whole)[rest_q[sel]]]
                if wholes.size:
                    shares[:, wholes] = 0.0
                    shares[k, wholes] = 1.0
            under[rest] = True


def run_reference(
    kernel: ReferenceKernel, spans: list[tuple[int, int]], workers: int, rows: int
) -> None:
    p = kernel.p
    _, w, c = p.shape
    n = len(p.frames)
    if workers == 1:
        scratch = Scratch(n, rows * w, c)
        for r0, r1 in spans:
            kernel.run(r0, r1, scratch)
        return
    scratches = [Scratch(n, rows * w, c) for _ in range(workers)]
    groups = [spans[i::workers] for i in range(workers)]

    def work(i: int) -> None:
        for r0, r1 in groups[i]:
            kernel.run(r0, r1, scratches[i])

    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(work, range(workers)))
