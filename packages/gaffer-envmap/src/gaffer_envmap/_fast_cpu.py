# pyright: reportReturnType=false, reportAssignmentType=false, reportArgumentType=false
# (numba kernels: their scalars are numpy float32, which pyright will not take for `float`)
"""Fused CPU kernel (numba) of the default encoding: world map + pose -> E_L, E_H.

The same mathematics as `conservative.rotate_conservative` followed by `encode._encode_finite` (its
reference twin; tests compare the two), in float32 with float64 only where sums must stay exact:

1. conservative pre-downsample and pole cells straight from the input (one read of the map);
2. per sub-sample: rotate the camera direction, (u, v) from polynomial atan2 / acos (errors 1e-6 rad and
   2e-8 rad, far below a texel), then the four bilinear taps on the reduced grid;
3. the taps' weights scattered into the coverage C_g (the adjoint of the lookup); per cell the gain
   Omega_g / C_g; per output pixel the gather of the gain-corrected cells;
4. E_L = clip(E, 0, 1)^(1/2.2) and E_H = log1p(10 E) / log1p(10 peak), with ln / exp2 from the float
   bits and short polynomials (relative error about 1e-7).

Every loop but the scatter of step 3 is plain arithmetic over contiguous structure-of-arrays buffers
that LLVM vectorises. What decides that, measured on the 2-core EPYC: `error_model="numpy"`
(numba's default Python error model guards every division with a ZeroDivisionError branch, which keeps
a loop scalar: the encoding stage took 3.7 ms per 256 x 256 map with it, 0.43 ms without), mantissa
bits read by an int -> float conversion rather than through a reinterpreting view, and floors written
as truncations of values known to be > -1.

Why numba: torch eager spends most of its time moving intermediate tensors through memory, and libm's
scalar atan2 / acos / pow / log1p alone cost about 8 ms per 256 x 256 map; numba compiles the loops
once (cached on disk) and needs no C compiler at install.
"""

import math
import os
import threading
from functools import lru_cache
from typing import Any, no_type_check

# numba picks TBB first when it can import it; an old system TBB then only warns (and pytest turns
# warnings into errors). The workqueue layer ships with numba, so choose it unless the user did
# (numba reads this when it is first imported).
os.environ.setdefault("NUMBA_THREADING_LAYER", "workqueue")

import numba
import numpy as np
from numba import njit, prange

from gaffer_envmap.conservative import (
    GROUP_SPAN,
    _sample_grid,
    conservative_height,
    reduced_grid,
    sample_spacing,
    sub_samples,
)
from gaffer_envmap.conventions import row_solid_angle

_TWO_PI = 2.0 * math.pi

# Every kernel is `@no_type_check`: numba compiles the Python function itself, so the jaxtyping +
# beartype hook of the tests must not wrap it (numba can neither compile nor cache the wrapper).


_f = np.float32
_A1, _A3, _A5, _A7, _A9, _A11 = (
    _f(0.99997726),
    _f(-0.33262347),
    _f(0.19354346),
    _f(-0.11643287),
    _f(0.05265332),
    _f(-0.01172120),
)
_C = tuple(
    _f(c)
    for c in (
        1.5707963050,
        -0.2145988016,
        0.0889789874,
        -0.0501743046,
        0.0308918810,
        -0.0170881256,
        0.0066700901,
        -0.0012624911,
    )
)
_C0, _C1, _C2, _C3, _C4, _C5, _C6, _C7 = _C
_PI = _f(math.pi)
_HALF_PI = _f(math.pi / 2)
_INV_TWO_PI = _f(1 / (2 * math.pi))
_INV_PI = _f(1 / math.pi)
_ZERO, _HALF, _ONE = _f(0.0), _f(0.5), _f(1.0)


@njit(inline="always", fastmath=True, error_model="numpy")
@no_type_check
def _atan2(y: float, x: float) -> float:
    """atan2 from a degree-11 odd minimax polynomial on [0, 1] (max error about 1e-6 rad), float32."""
    ax, ay = abs(x), abs(y)
    mx, mn = max(ax, ay), min(ax, ay)
    a = mn / mx if mx > _ZERO else _ZERO
    s = a * a
    r = a * (_A1 + s * (_A3 + s * (_A5 + s * (_A7 + s * (_A9 + s * _A11)))))
    r = _HALF_PI - r if ay > ax else r
    r = _PI - r if x < _ZERO else r
    return -r if y < _ZERO else r


@njit(inline="always", fastmath=True, error_model="numpy")
@no_type_check
def _acos(z: float) -> float:
    """acos from Abramowitz & Stegun 4.4.46 (max error 2e-8 rad; float32 here)."""
    a = min(abs(z), _ONE)
    p = _C0 + a * (_C1 + a * (_C2 + a * (_C3 + a * (_C4 + a * (_C5 + a * (_C6 + a * _C7))))))
    r = math.sqrt(_ONE - a) * p
    return _PI - r if z < _ZERO else r


_SQRT2 = _f(math.sqrt(2.0))
_LN2 = _f(math.log(2.0))
_LOG2_TO_LDR = _f(1 / (2.2 * math.log(2.0)))  # ln(x) -> log2(x) / 2.2
_T3, _T5, _T7, _T9 = _f(1 / 3), _f(1 / 5), _f(1 / 7), _f(1 / 9)
_E2, _E3, _E4, _E5, _E6, _E7 = (_f(1 / math.factorial(k)) for k in range(2, 8))
_TWO, _TEN, _BIG = _f(2.0), _f(10.0), _f(3.4e37)
_MANT = _f(2.0**-23)
_K64 = _f(64.0)


@njit(inline="always", fastmath=True, error_model="numpy")
@no_type_check
def _ln_bits(b: int) -> float:
    """ln(x) of a positive normal float32 x from its bits `b` (int32): x = m 2^e with m in [1, 2) read as
    an integer -> float conversion of the mantissa bits (exact; no reinterpreting view, which LLVM
    will not vectorise); m moved into [sqrt(1/2), sqrt(2)); ln(m) = 2 atanh(z), z = (m - 1) / (m + 1),
    |z| <= 0.172 (series to z^9: below float32 rounding)."""
    e = _f((b >> 23) & 0xFF) - _f(127.0)
    m = _ONE + _f(b & 0x7FFFFF) * _MANT
    big = m > _SQRT2
    m = m * _HALF if big else m
    e = e + _ONE if big else e
    z = (m - _ONE) / (m + _ONE)
    z2 = z * z
    return e * _LN2 + _TWO * z * (_ONE + z2 * (_T3 + z2 * (_T5 + z2 * (_T7 + z2 * _T9))))


@no_type_check
def _stage_cells(
    src: np.ndarray,
    fac: int,
    dz: np.ndarray,
    cells: np.ndarray,
    starts: np.ndarray,
    lbar: np.ndarray,
) -> float:
    """Cell means `lbar` `[G, 3]` straight from the input `[He_in, We_in, 3]` (pre-downsample by `fac`
    with solid-angle weights `dz` per input row, then pole cells); returns the pre-downsampled peak."""
    he = cells.shape[0]
    ws = src.shape[1] // fac
    peak = _ZERO
    if fac == 1:
        flat = src.reshape(src.size)
        for i in range(flat.shape[0]):
            peak = max(peak, flat[i])
        for r in range(he):
            k = ws // cells[r]
            s0 = starts[r]
            if k == 1:
                lbar[s0 : s0 + ws] = src[r]  # a slice copy: no wraparound code, vectorised
            else:
                inv = _ONE / _f(k)
                for g in range(cells[r]):
                    a0 = _ZERO
                    a1 = _ZERO
                    a2 = _ZERO
                    for q in range(k):
                        a0 += src[r, g * k + q, 0]
                        a1 += src[r, g * k + q, 1]
                        a2 += src[r, g * k + q, 2]
                    lbar[s0 + g, 0] = a0 * inv
                    lbar[s0 + g, 1] = a1 * inv
                    lbar[s0 + g, 2] = a2 * inv
        return peak
    peak64 = 0.0
    row = np.empty(3 * ws, np.float64)
    for r in range(he):
        row[:] = 0.0
        wsum = 0.0
        for i in range(fac):
            w = dz[r * fac + i]
            wsum += w
            line = src[r * fac + i].reshape(3 * fac * ws)
            for j in range(ws):
                for q in range(fac):
                    b = 3 * (j * fac + q)
                    row[3 * j] += w * line[b]
                    row[3 * j + 1] += w * line[b + 1]
                    row[3 * j + 2] += w * line[b + 2]
        norm = 1.0 / (wsum * fac)
        for i in range(3 * ws):
            v = row[i] * norm
            row[i] = v
            peak64 = max(peak64, v)
        k = ws // cells[r]
        for g in range(cells[r]):
            for c in range(3):
                acc = 0.0
                for q in range(k):
                    acc += row[3 * (g * k + q) + c]
                lbar[starts[r] + g, c] = acc / k
    return peak64


@no_type_check
def _stage_uv(
    dx: np.ndarray,
    dy: np.ndarray,
    dz: np.ndarray,
    m: np.ndarray,
    fhe: float,
    uu: np.ndarray,
    yy: np.ndarray,
) -> None:
    """Source u and row coordinate y = v He - 1/2 of the sub-samples (camera directions as planes `dx`,
    `dy`, `dz`; lookup d_world = d_cam @ m): branch-free, vectorised. Loops run over `range(len)` of
    arrays the caller slices: an index that could be negative (a `range(lo, hi)`) makes numba add
    wraparound code that stops LLVM vectorising (measured 4.5 vs 0.9 ms for the encoding)."""
    m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
    m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
    m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
    for s in range(uu.shape[0]):
        x, y, z = dx[s], dy[s], dz[s]
        wx = x * m00 + y * m10 + z * m20
        wy = x * m01 + y * m11 + z * m21
        wz = x * m02 + y * m12 + z * m22
        uu[s] = _HALF - _atan2(wy, wx) * _INV_TWO_PI
        yy[s] = _acos(wz) * _INV_PI * fhe - _HALF


@no_type_check
def _stage_taps_band(
    uu: np.ndarray,
    yy: np.ndarray,
    band_lo: int,
    band_hi: int,
    band_start: int,
    width: int,
    i0: np.ndarray,
    i1: np.ndarray,
    i2: np.ndarray,
    i3: np.ndarray,
    w0: np.ndarray,
    w1: np.ndarray,
    w2: np.ndarray,
    w3: np.ndarray,
    slow: np.ndarray,
) -> None:
    """The four bilinear taps (flat cell, weight) on the reduced grid (see `conservative.cell_taps`) of
    sub-samples whose two rows lie in the band [band_lo, band_hi) of whole rows
    (no pole groups: `width` cells a row, row r starting at band_start + (r - band_lo) width), written
    without table lookups so that LLVM vectorises it (a gather of the row table keeps the loop scalar on
    this CPU). Every other sample (pole rows, pole crossings) is flagged in `slow` for the scalar
    `_stage_fix_cover`, which overwrites its taps."""
    fw = _f(width)
    for s in range(uu.shape[0]):
        u = uu[s]
        y = yy[s]  # >= -1/2
        y0 = np.int32(y + _ONE) - np.int32(1)
        fy = y - _f(y0)
        out = (y0 < band_lo) | (y0 + 1 >= band_hi)
        slow[s] = out
        x = u * fw - _HALF
        xi = np.int32(x + _ONE) - np.int32(1)
        fx = x - _f(xi)
        j0 = xi + width if xi < 0 else (xi - width if xi >= width else xi)
        j1 = j0 + 1 if j0 + 1 < width else j0 + 1 - width
        r0 = min(max(y0, band_lo), band_hi - 2)  # kept in range for flagged samples too
        base = band_start + (r0 - band_lo) * width
        i0[s] = base + j0
        i1[s] = base + j1
        i2[s] = base + width + j0
        i3[s] = base + width + j1
        w0[s] = (_ONE - fy) * (_ONE - fx)
        w1[s] = (_ONE - fy) * fx
        w2[s] = fy * (_ONE - fx)
        w3[s] = fy * fx


@no_type_check
def _stage_fix_cover(
    uu: np.ndarray,
    yy: np.ndarray,
    cells: np.ndarray,
    starts: np.ndarray,
    slow: np.ndarray,
    i0: np.ndarray,
    i1: np.ndarray,
    i2: np.ndarray,
    i3: np.ndarray,
    w0: np.ndarray,
    w1: np.ndarray,
    w2: np.ndarray,
    w3: np.ndarray,
    w_s: np.ndarray,
    cover: np.ndarray,
) -> None:
    """Taps of the flagged samples through the row table (pole rows have fewer, wider cells; the row
    beyond a pole is the edge row turned by half; floors are truncations of values > -1 and the column
    wrap is at most one period), then every sample's weights times w_s scattered into the coverage
    C_g = sum_s w_s b(s, g) (float64), the adjoint of the lookup: the one scalar loop."""
    he = cells.shape[0]
    for s in range(uu.shape[0]):
        if slow[s]:
            u = uu[s]
            y = yy[s]
            y0 = np.int32(y + _ONE) - np.int32(1)
            fy = y - _f(y0)
            r0 = max(y0, np.int32(0))
            u0 = u + _HALF if y0 < 0 else u
            n0 = cells[r0]
            x = u0 * _f(n0) - _HALF
            xi = np.int32(x + _ONE) - np.int32(1)
            fx0 = x - _f(xi)
            j0 = xi + n0 if xi < 0 else (xi - n0 if xi >= n0 else xi)
            j1 = j0 + 1 if j0 + 1 < n0 else j0 + 1 - n0
            r1 = min(y0 + np.int32(1), np.int32(he - 1))
            u1 = u + _HALF if y0 + 1 >= he else u
            n1 = cells[r1]
            x = u1 * _f(n1) - _HALF
            xi = np.int32(x + _ONE) - np.int32(1)
            fx1 = x - _f(xi)
            k0 = xi + n1 if xi < 0 else (xi - n1 if xi >= n1 else xi)
            k1 = k0 + 1 if k0 + 1 < n1 else k0 + 1 - n1
            i0[s] = starts[r0] + j0
            i1[s] = starts[r0] + j1
            i2[s] = starts[r1] + k0
            i3[s] = starts[r1] + k1
            w0[s] = (_ONE - fy) * (_ONE - fx0)
            w1[s] = (_ONE - fy) * fx0
            w2[s] = fy * (_ONE - fx1)
            w3[s] = fy * fx1
        ws_ = np.float64(w_s[s])
        cover[i0[s]] += ws_ * w0[s]
        cover[i1[s]] += ws_ * w1[s]
        cover[i2[s]] += ws_ * w2[s]
        cover[i3[s]] += ws_ * w3[s]


@no_type_check
def _stage_gains(
    lbar: np.ndarray, cover: np.ndarray, omega_cell: np.ndarray, corrected: np.ndarray
) -> int:
    """corrected_g = L_g Omega_g / C_g (0 where unread); returns how many unread cells carry light."""
    n = cover.shape[0]
    for g in range(n):
        c = cover[g]
        gain = _f(omega_cell[g] / c) if c > 0.0 else _ZERO
        corrected[g, 0] = lbar[g, 0] * gain
        corrected[g, 1] = lbar[g, 1] * gain
        corrected[g, 2] = lbar[g, 2] * gain
    lost = 0
    for g in range(n):
        if cover[g] == 0.0 and (lbar[g, 0] != 0 or lbar[g, 1] != 0 or lbar[g, 2] != 0):
            lost += 1
    return lost


@no_type_check
def _stage_gather(
    corrected: np.ndarray,
    i0: np.ndarray,
    i1: np.ndarray,
    i2: np.ndarray,
    i3: np.ndarray,
    w0: np.ndarray,
    w1: np.ndarray,
    w2: np.ndarray,
    w3: np.ndarray,
    w_rows: np.ndarray,
    inv_om: np.ndarray,
    ssv: int,
    ssu: int,
    rad: np.ndarray,
    lo: int,
    hi: int,
) -> None:
    """Output radiance rows [lo, hi) of `rad` `[3, h, w]`: per pixel, the w_s-weighted sum of its
    sub-samples' bilinear lookups of the gain-corrected cells `corrected` `[G, 3]`, over Omega_o.
    Each sub-sample row is first gathered into a row buffer (a vectorised gather loop), then summed
    into pixels."""
    out_w = rad.shape[2]
    ws = out_w * ssu
    flat = corrected.reshape(corrected.size)
    b0 = np.empty(ws, np.float32)
    b1 = np.empty(ws, np.float32)
    b2 = np.empty(ws, np.float32)
    for o in range(lo, hi):
        for col in range(out_w):
            rad[0, o, col] = _ZERO
            rad[1, o, col] = _ZERO
            rad[2, o, col] = _ZERO
        for i in range(ssv):
            row = o * ssv + i
            base = row * ws
            ia, ib, ic, id_ = (
                i0[base : base + ws],
                i1[base : base + ws],
                i2[base : base + ws],
                i3[base : base + ws],
            )
            wa_, wb_, wc_, wd_ = (
                w0[base : base + ws],
                w1[base : base + ws],
                w2[base : base + ws],
                w3[base : base + ws],
            )
            for q in range(ws):
                a, b, c, d = 3 * ia[q], 3 * ib[q], 3 * ic[q], 3 * id_[q]
                wa, wb, wc, wd = wa_[q], wb_[q], wc_[q], wd_[q]
                b0[q] = wa * flat[a] + wb * flat[b] + wc * flat[c] + wd * flat[d]
                b1[q] = wa * flat[a + 1] + wb * flat[b + 1] + wc * flat[c + 1] + wd * flat[d + 1]
                b2[q] = wa * flat[a + 2] + wb * flat[b + 2] + wc * flat[c + 2] + wd * flat[d + 2]
            wgt = w_rows[row] * inv_om[o]
            for col in range(out_w):
                a0 = _ZERO
                a1 = _ZERO
                a2 = _ZERO
                for q in range(ssu):
                    a0 += b0[col * ssu + q]
                    a1 += b1[col * ssu + q]
                    a2 += b2[col * ssu + q]
                rad[0, o, col] += wgt * a0
                rad[1, o, col] += wgt * a1
                rad[2, o, col] += wgt * a2


@no_type_check
def _stage_encode(
    rad: np.ndarray,
    inv_log_peak: float,
    s0: np.ndarray,
    s1: np.ndarray,
    ib: np.ndarray,
    ldr: np.ndarray,
    hdr: np.ndarray,
) -> None:
    """E_L and E_H of radiance `rad` (flat, channels-first). `s0`, `s1`
    (float32) and `ib` (int32) are flat work space: clipped values, 1 + 10 E, and 2^floor(y) as bits."""
    inv = _f(inv_log_peak)
    for i in range(rad.shape[0]):
        v = min(max(rad[i], _ZERO), _BIG)
        s0[i] = min(v, _ONE)
        s1[i] = _ONE + _TEN * v
    bits0 = s0.view(np.int32)
    bits1 = s1.view(np.int32)
    for i in range(rad.shape[0]):
        # E_L = 2^y, y = log2(x) / 2.2 <= 0 (x in (0, 1]): 2^(y - floor y) by series here, 2^floor(y)
        # as exponent bits (y > -64 for every normal float32).
        y = _ln_bits(bits0[i]) * _LOG2_TO_LDR
        k = np.int32(_K64 + y) - np.int32(64)
        t = (y - _f(k)) * _LN2
        p = _ONE + t * (_ONE + t * (_E2 + t * (_E3 + t * (_E4 + t * (_E5 + t * (_E6 + t * _E7))))))
        ldr[i] = p if s0[i] > _ZERO else _ZERO
        ib[i] = (k + np.int32(127)) << np.int32(23)
        # log1p(a) = ln(1 + a) + (a - ((1 + a) - 1)) / (1 + a): the rounding of 1 + a put back.
        x1 = s1[i]
        a = _TEN * min(max(rad[i], _ZERO), _BIG)
        ln1 = _ln_bits(bits1[i]) + (a - (x1 - _ONE)) / x1
        hdr[i] = min(max(ln1 * inv, _ZERO), _ONE)
    scale = ib.view(np.float32)
    for i in range(rad.shape[0]):
        ldr[i] = ldr[i] * scale[i]


@no_type_check
def _splat_lost(
    lbar: np.ndarray,
    cover: np.ndarray,
    omega_cell: np.ndarray,
    row_of: np.ndarray,
    cells: np.ndarray,
    starts: np.ndarray,
    m: np.ndarray,
    om_out: np.ndarray,
    rad: np.ndarray,
) -> None:
    """Deposit each unread cell's power into the output pixel holding its centre (`rad` `[3, h, w]`)."""
    he = cells.shape[0]
    out_h, out_w = rad.shape[1], rad.shape[2]
    for g in range(cover.shape[0]):
        if cover[g] > 0 or (lbar[g, 0] == 0 and lbar[g, 1] == 0 and lbar[g, 2] == 0):
            continue
        r = row_of[g]
        theta = (r + 0.5) * math.pi / he
        phi = _TWO_PI * (0.5 - (g - starts[r] + 0.5) / cells[r])
        d = (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))
        c = [
            m[i, 0] * d[0] + m[i, 1] * d[1] + m[i, 2] * d[2] for i in range(3)
        ]  # d_cam = m d_world
        tc = math.acos(min(max(c[1], -1.0), 1.0))
        uc = 0.5 - math.atan2(-c[2], c[0]) / _TWO_PI
        uc = uc - math.floor(uc)
        ro = min(int(tc / math.pi * out_h), out_h - 1)
        co = int(uc * out_w) % out_w
        for ch in range(3):
            rad[ch, ro, co] += lbar[g, ch] * omega_cell[g] / om_out[ro]


_jit = njit(fastmath=True, cache=True, nogil=True, error_model="numpy")
_stage_cells = _jit(_stage_cells)
_stage_uv = _jit(_stage_uv)
_stage_taps_band = _jit(_stage_taps_band)
_stage_fix_cover = _jit(_stage_fix_cover)
_stage_gains = _jit(_stage_gains)
_stage_gather = _jit(_stage_gather)
_stage_encode = _jit(_stage_encode)
_splat_lost = _jit(_splat_lost)


@_jit
@no_type_check
def _inv_log_peak(peak: float) -> float:
    """1 / log1p(10 peak) as `encode.hdr_encode` takes it (0 for an all-black map)."""
    denom = math.log1p(10.0 * min(max(peak, 0.0), 3.4e38 / 40.0))
    return 1.0 / denom if denom > 0 else 0.0


@no_type_check
def _encode_split(
    src,
    m,
    fac,
    dz_rows,
    cells,
    starts,
    row_of,
    omega_cell,
    dx,
    dy,
    dz,
    w_samp,
    w_rows,
    om_out,
    inv_om,
    ssv,
    ssu,
    band,
    chunks,
    ldr,
    hdr,
    uu,
    yy,
    i0,
    i1,
    i2,
    i3,
    w0,
    w1,
    w2,
    w3,
    slow,
    covers,
    lbar,
    corrected,
    rad,
    s0,
    s1,
    ib,
):  # type: ignore[no-untyped-def]
    """One map, its stages split over `chunks` threads: sub-sample rows for the lookup and the coverage
    (a partial coverage per chunk in `covers` `[chunks, G]`, summed after), output rows for the gather
    and the encodings. Every buffer comes from the caller (`_workspace`): allocating them per call
    (23 MB at 256 x 256, supersample 2) cost as much as the arithmetic, in page faults."""
    out_h, out_w = ldr.shape[1], ldr.shape[2]
    peak = _stage_cells(src, fac, dz_rows, cells, starts, lbar)
    rows_s = out_h * ssv
    ws = out_w * ssu
    covers[:] = 0.0
    fhe = _f(cells.shape[0])
    for c in prange(chunks):
        lo = (rows_s * c // chunks) * ws
        hi = (rows_s * (c + 1) // chunks) * ws
        _stage_uv(dx[lo:hi], dy[lo:hi], dz[lo:hi], m, fhe, uu[lo:hi], yy[lo:hi])
        _stage_taps_band(
            uu[lo:hi],
            yy[lo:hi],
            band[0],
            band[1],
            band[2],
            band[3],
            i0[lo:hi],
            i1[lo:hi],
            i2[lo:hi],
            i3[lo:hi],
            w0[lo:hi],
            w1[lo:hi],
            w2[lo:hi],
            w3[lo:hi],
            slow[lo:hi],
        )
        _stage_fix_cover(
            uu[lo:hi],
            yy[lo:hi],
            cells,
            starts,
            slow[lo:hi],
            i0[lo:hi],
            i1[lo:hi],
            i2[lo:hi],
            i3[lo:hi],
            w0[lo:hi],
            w1[lo:hi],
            w2[lo:hi],
            w3[lo:hi],
            w_samp[lo:hi],
            covers[c],
        )
    cover = covers[0]
    for c in range(1, chunks):
        cover += covers[c]
    lost = _stage_gains(lbar, cover, omega_cell, corrected)
    for c in prange(chunks):
        _stage_gather(
            corrected,
            i0,
            i1,
            i2,
            i3,
            w0,
            w1,
            w2,
            w3,
            w_rows,
            inv_om,
            ssv,
            ssu,
            rad,
            out_h * c // chunks,
            out_h * (c + 1) // chunks,
        )
    if lost > 0:
        _splat_lost(lbar, cover, omega_cell, row_of, cells, starts, m, om_out, rad)
    inv = _inv_log_peak(peak)
    n = 3 * out_h * out_w
    flat_rad = rad.reshape(n)
    flat_ldr = ldr.reshape(n)
    flat_hdr = hdr.reshape(n)
    for c in prange(chunks):
        lo = n * c // chunks
        hi = n * (c + 1) // chunks
        _stage_encode(
            flat_rad[lo:hi], inv, s0[lo:hi], s1[lo:hi], ib[lo:hi], flat_ldr[lo:hi], flat_hdr[lo:hi]
        )


# The serial build runs inside `_encode_batch`'s threads (numba's workqueue layer does not nest
# parallel regions); the parallel one splits a single map.
_encode_split_serial = _jit(_encode_split)
_encode_split = njit(fastmath=True, cache=True, nogil=True, parallel=True, error_model="numpy")(
    _encode_split
)


@njit(fastmath=True, cache=True, nogil=True, parallel=True, error_model="numpy")
@no_type_check
def _encode_batch(
    src,
    m,
    fac,
    dz_rows,
    cells,
    starts,
    row_of,
    omega_cell,
    dx,
    dy,
    dz,
    w_samp,
    w_rows,
    om_out,
    inv_om,
    ssv,
    ssu,
    band,
    ldr,
    hdr,
    uu,
    yy,
    i0,
    i1,
    i2,
    i3,
    w0,
    w1,
    w2,
    w3,
    slow,
    covers,
    lbar,
    corrected,
    rad,
    s0,
    s1,
    ib,
):  # type: ignore[no-untyped-def]
    """Maps in parallel: worker k (its own buffers, row k of each) takes maps k, k + K, ... whole, so no
    synchronisation and batching never costs per map."""
    workers = uu.shape[0]
    for k in prange(workers):
        for b in range(k, src.shape[0], workers):
            _encode_split_serial(
                src[b],
                m[b],
                fac,
                dz_rows,
                cells,
                starts,
                row_of,
                omega_cell,
                dx,
                dy,
                dz,
                w_samp,
                w_rows,
                om_out,
                inv_om,
                ssv,
                ssu,
                band,
                1,
                ldr[b],
                hdr[b],
                uu[k],
                yy[k],
                i0[k],
                i1[k],
                i2[k],
                i3[k],
                w0[k],
                w1[k],
                w2[k],
                w3[k],
                slow[k],
                covers[k],
                lbar[k],
                corrected[k],
                rad[k],
                s0[k],
                s1[k],
                ib[k],
            )


def _whole_row_band(cells: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """(first row, end row, first cell, width) of the longest run of whole rows (no pole groups), int32;
    an empty band (2 rows needed) flags every sample for the scalar path."""
    best = (0, 0)
    r = 0
    while r < len(cells):
        if cells[r] == width:
            e = r
            while e < len(cells) and cells[e] == width:
                e += 1
            if e - r > best[1] - best[0]:
                best = (r, e)
            r = e
        else:
            r += 1
    lo, hi = best if best[1] - best[0] >= 2 else (0, 0)
    return np.array([lo, hi, starts[lo] if hi > lo else 0, width], np.int32)


@lru_cache(maxsize=16)
def _plan(src_h: int, size: int, ss: int) -> tuple:  # type: ignore[type-arg]
    """Everything that depends on sizes only (directions, weights, the reduced grid)."""
    hs = conservative_height(src_h, size, size, ss)
    ssv, ssu = sub_samples(size, size, ss)
    cells, starts = reduced_grid(hs, 2 * hs, GROUP_SPAN * sample_spacing(size, size, ss))
    z = np.cos(np.arange(src_h + 1) * np.pi / src_h)
    dz = z[:-1] - z[1:]
    omega_cell = np.repeat(row_solid_angle(hs, 2 * hs) * (2 * hs / cells), cells)
    dirs, w_rows = _sample_grid(size, size, ssv, ssu)
    return (
        src_h // hs,
        dz,
        cells.astype(np.int32),
        starts.astype(np.int32),
        np.repeat(np.arange(hs), cells).astype(np.int64),
        omega_cell,
        *(np.ascontiguousarray(dirs[..., k].reshape(-1), np.float32) for k in range(3)),  # planes
        np.repeat(w_rows, size * ssu).astype(np.float32),  # w_s per sub-sample
        w_rows.astype(np.float32),
        row_solid_angle(size, size),
        (1 / row_solid_angle(size, size)).astype(np.float32),
        ssv,
        ssu,
        _whole_row_band(cells, starts, 2 * hs),
    )


def _workspace(plan: tuple, size: int, workers: int, chunks: int) -> list[np.ndarray]:  # type: ignore[type-arg]
    """Work buffers for `workers` maps at once, each split over `chunks` threads, reused across calls
    (one set per Python thread: calls from several threads at once must not share them)."""
    cache: dict = getattr(_LOCAL, "cache", None) or {}  # type: ignore[type-arg]
    _LOCAL.cache = cache
    n_s, n_cells = plan[6].shape[0], plan[5].shape[0]  # dx, omega_cell
    key = (n_s, n_cells, size, workers, chunks)
    if key not in cache:
        n = 3 * size * size
        k = workers
        f32, i32 = np.float32, np.int32
        cache.clear()  # one size at a time: keep memory bounded
        cache[key] = [
            np.empty((k, n_s), f32),  # uu
            np.empty((k, n_s), f32),  # yy
            *(np.empty((k, n_s), i32) for _ in range(4)),  # taps
            *(np.empty((k, n_s), f32) for _ in range(4)),  # weights
            np.empty((k, n_s), np.bool_),  # slow
            np.empty((k, chunks, n_cells), np.float64),  # partial coverages
            np.empty((k, n_cells, 3), f32),  # lbar
            np.empty((k, n_cells, 3), f32),  # corrected
            np.empty((k, 3, size, size), f32),  # radiance
            np.empty((k, n), f32),
            np.empty((k, n), f32),
            np.empty((k, n), i32),
        ]
    return cache[key]


_LOCAL = threading.local()


def encode_conservative_cpu(
    src: np.ndarray, m: np.ndarray, size: int, ss: int, threads: int
) -> tuple[np.ndarray, np.ndarray]:
    """E_L, E_H `[B, 3, size, size]` float32 of finite float32 maps `src` `[B, He, 2He, 3]` under lookup
    rotations `m` `[B, 3, 3]` (d_world = m^T d_cam), the conservative filter at supersample `ss`."""
    plan = _plan(src.shape[1], size, ss)
    b = src.shape[0]
    ldr = np.empty((b, 3, size, size), np.float32)
    hdr = np.empty((b, 3, size, size), np.float32)
    threads = max(1, min(threads, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    numba.set_num_threads(threads)
    mf = np.ascontiguousarray(m, np.float32)
    src = np.ascontiguousarray(src, np.float32)
    # (argument lists: `plan` is a tuple of unknown length to the type checker)
    if b >= threads:
        work = _workspace(plan, size, threads, 1)
        batch_args: list[Any] = [src, mf, *plan, ldr, hdr, *work]
        _encode_batch(*batch_args)
    else:
        # Fewer maps than threads (one map at a time): split each map's stages over the threads.
        work = [w[0] for w in _workspace(plan, size, 1, threads)]
        for i in range(b):
            split_args: list[Any] = [src[i], mf[i], *plan, threads, ldr[i], hdr[i], *work]
            _encode_split(*split_args)
    return ldr, hdr
