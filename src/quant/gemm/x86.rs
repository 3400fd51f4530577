//! x86_64 kernels: AVX-512 VNNI, AVX-VNNI and AVX2.
//!
//! All read panels packed `[kp / 4][pw][4]`: for k-group g, the 4 weights of column j are
//! one i32 lane, so one vector holds 16 (zmm) or 8 (ymm) columns. Four consecutive
//! activation bytes of a row are broadcast as one i32 lane and `vpdpbusd` (u8 x i8, four
//! products summed into i32) accumulates a register tile of MR rows x NV vectors. AVX2
//! emulates `vpdpbusd` with `vpmaddubsw` (pairs to i16: no saturation with u7 activations)
//! and `vpmaddwd` by ones. The output stage runs on the registers: sub, convert, mul, add,
//! max with the same IEEE operations as the scalar code, hence the same bits.
//!
//! Rows past m in the last row tile repeat the last row (computed, never stored); the k tail
//! (k % 4) is read through a zero-padded copy; columns past n are zero in the packing and
//! masked at the store.

// Register tiles are indexed by (row, vector): ranges read better than iterator chains here.
#![allow(clippy::needless_range_loop)]

use std::arch::x86_64::*;
use std::ptr;

use super::{Dst, Job, RowBlocks, quantize_one, row_ptrs};

/// The k tail: bytes `4 * full .. k` of each row, zero-padded to one group.
///
/// # Safety
/// Each pointer in `rows` is a row of at least `k` bytes.
#[inline(always)]
unsafe fn tail_words<const MR: usize>(rows: &[*const u8; MR], k: usize) -> [[u8; 4]; MR] {
    let mut tail = [[0u8; 4]; MR];
    for r in 0..MR {
        for t in 0..3 {
            if k / 4 * 4 + t < k {
                // SAFETY: a byte below k of a row of k bytes.
                tail[r][t] = unsafe { *rows[r].add(k / 4 * 4 + t) };
            }
        }
    }
    tail
}

/// Bit mask of the first `c` of 16 lanes.
#[inline(always)]
fn mask16(c: usize) -> u16 {
    if c >= 16 { u16::MAX } else { (1u16 << c) - 1 }
}

// ---------------------------------------------------------------------------------------
// AVX-512 VNNI: panels of up to 64 columns (4 zmm), tiles 6x4, 8x3, 12x2 or 16x1 vectors.
// ---------------------------------------------------------------------------------------

/// # Safety
/// `job` comes from `qgemm` (checked), the CPU has avx512f, avx512bw, avx512vl and avx512vnni,
/// and the
/// weights are packed for [`super::Kernel::Avx512Vnni`].
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512vnni")]
pub(super) unsafe fn gemm_avx512(job: &Job<'_>) {
    let data = job.w.data().as_ptr();
    for (j0, pw, off) in job.w.panels() {
        // SAFETY: every panel lies inside the packed data.
        let panel = unsafe { data.add(off) };
        // SAFETY (each arm): forwarded; the panel is `pw` = 16 * NV columns wide.
        match pw / 16 {
            4 => unsafe { panel512::<6, 4>(job, panel, j0) },
            3 => unsafe { panel512::<8, 3>(job, panel, j0) },
            2 => unsafe { panel512::<12, 2>(job, panel, j0) },
            _ => unsafe { panel512::<16, 1>(job, panel, j0) },
        }
    }
}

#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512vnni")]
unsafe fn panel512<const MR: usize, const NV: usize>(job: &Job<'_>, panel: *const i8, j0: usize) {
    let mut blocks = RowBlocks::new(job, MR, 16 * NV);
    for ib in (0..job.m).step_by(blocks.rows) {
        let end = (ib + blocks.rows).min(job.m);
        let (dst, oi, oj) = blocks.target(job, ib, j0);
        for i0 in (ib..end).step_by(MR) {
            // SAFETY: forwarded; 1 <= rows <= end - i0; the target holds the block.
            unsafe { tile512::<MR, NV>(job, panel, j0, i0, MR.min(end - i0), dst, oi + i0 - ib, oj) };
        }
        // SAFETY: rows ib..end < m, columns j0.. below n.
        unsafe { blocks.flush(job, ib, end - ib, j0, (16 * NV).min(job.n - j0)) };
    }
}

/// One k-group: `acc[r][v] += dot4(a[r][off..off + 4], b[v])`.
#[inline(always)]
unsafe fn step512<const MR: usize, const NV: usize>(
    acc: &mut [[__m512i; NV]; MR],
    rows: &[*const u8; MR],
    off: usize,
    b: *const i8,
) {
    // SAFETY: the caller passes a k-group inside the panel and 4 readable bytes per row;
    // the intrinsics' features are enabled in every (inlining) caller.
    unsafe {
        let mut bv = [_mm512_setzero_si512(); NV];
        for v in 0..NV {
            bv[v] = _mm512_loadu_si512(b.add(64 * v).cast());
        }
        for r in 0..MR {
            let x = _mm512_set1_epi32(rows[r].add(off).cast::<i32>().read_unaligned());
            for v in 0..NV {
                acc[r][v] = _mm512_dpbusd_epi32(acc[r][v], x, bv[v]);
            }
        }
    }
}

/// u7 requantisation of 16 lanes, as `quantize_one`: NaN -> 0 before rounding (so the zero
/// point comes out), then clamping to ±256 (beyond it the result is 0 or 127 anyway).
#[inline]
#[target_feature(enable = "avx512f")]
fn requant512(v: __m512, inv_scale: __m512, zp: __m512i) -> __m512i {
    let t = _mm512_mul_ps(v, inv_scale);
    let t = _mm512_maskz_mov_ps(_mm512_cmp_ps_mask::<_CMP_ORD_Q>(t, t), t);
    let t = _mm512_min_ps(_mm512_max_ps(t, _mm512_set1_ps(-256.0)), _mm512_set1_ps(256.0));
    let q = _mm512_add_epi32(_mm512_cvt_roundps_epi32::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(t), zp);
    _mm512_min_epi32(_mm512_max_epi32(q, _mm512_setzero_si512()), _mm512_set1_epi32(127))
}

/// Stores the first `c` (1..=16) of 16 lanes in 0..=127 as bytes. (The register form of
/// vpmovdb and a plain store: the masked memory form is slow on AMD Zen 4.)
///
/// # Safety
/// `dst` is valid for `c` bytes.
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn store_u7x16(dst: *mut u8, q: __m512i, c: usize) {
    let bytes = _mm512_cvtepi32_epi8(q);
    // SAFETY: 16 bytes when c == 16, else c bytes through a copy.
    unsafe {
        if c >= 16 {
            _mm_storeu_si128(dst.cast(), bytes);
        } else {
            let mut t = [0u8; 16];
            _mm_storeu_si128(t.as_mut_ptr().cast(), bytes);
            ptr::copy_nonoverlapping(t.as_ptr(), dst, c);
        }
    }
}

/// One tile: rows `i0..i0 + rows` (the tile computes MR, repeating the last row) times the
/// panel at column `j0`, stored into `dst` with its (row 0, column 0) at output (oi, oj).
///
/// # Safety
/// Rows exist, the panel is packed for this kernel, and `dst` holds `rows` rows and the
/// panel's valid columns from (oi, oj).
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512vnni")]
#[allow(clippy::too_many_arguments)]
unsafe fn tile512<const MR: usize, const NV: usize>(
    job: &Job<'_>,
    panel: *const i8,
    j0: usize,
    i0: usize,
    rows: usize,
    dst: Dst,
    oi: usize,
    oj: usize,
) {
    let (k, pw) = (job.k, 16 * NV);
    // SAFETY: rows i0..i0 + rows exist.
    let rowp = unsafe { row_ptrs::<MR>(job, i0, rows) };
    let mut acc = [[_mm512_setzero_si512(); NV]; MR];
    for g in 0..k / 4 {
        // SAFETY: group g < kp / 4 of the panel; bytes 4g..4g + 4 <= k of each row.
        unsafe { step512(&mut acc, &rowp, 4 * g, panel.add(4 * pw * g)) };
    }
    if k % 4 != 0 {
        // SAFETY: rows of k bytes; the padded group k / 4 is inside the panel.
        unsafe {
            let tail = tail_words(&rowp, k);
            let tp = tail.each_ref().map(|t| t.as_ptr());
            step512(&mut acc, &tp, 0, panel.add(4 * pw * (k / 4)));
        }
    }

    // Output stage on the registers. The per-column vectors are padded to whole panels.
    let mut f = [[_mm512_setzero_ps(); NV]; MR];
    for v in 0..NV {
        let j = j0 + 16 * v;
        // SAFETY: j + 16 <= n_pad, the length of zc, scale and bias.
        let (zc, scale, bias) = unsafe {
            (
                _mm512_loadu_si512(job.zc.as_ptr().add(j).cast()),
                _mm512_loadu_ps(job.scale.as_ptr().add(j)),
                job.bias.as_ref().map(|b| b.as_ptr().add(j)),
            )
        };
        for r in 0..MR {
            let mut y = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_sub_epi32(acc[r][v], zc)), scale);
            if let Some(b) = bias {
                // SAFETY: as above.
                y = _mm512_add_ps(y, unsafe { _mm512_loadu_ps(b) });
            }
            if job.relu {
                // maxps returns its second operand for NaN and for ±0: v > 0 ? v : +0.
                y = _mm512_max_ps(y, _mm512_setzero_ps());
            }
            f[r][v] = y;
        }
    }
    let cols = pw.min(job.n - j0);
    match dst {
        Dst::F32 { ptr, ld } => {
            for r in 0..rows {
                for v in 0..NV {
                    let mask = mask16(cols.saturating_sub(16 * v));
                    // SAFETY: row oi + r of the target; the mask keeps columns below n.
                    unsafe { _mm512_mask_storeu_ps(ptr.add((oi + r) * ld + oj + 16 * v), mask, f[r][v]) };
                }
            }
        }
        Dst::U7 { ptr, ld, inv_scale, zp } => {
            let (inv, zp) = (_mm512_set1_ps(inv_scale), _mm512_set1_epi32(zp));
            for r in 0..rows {
                for v in 0..NV {
                    let c = cols.saturating_sub(16 * v).min(16);
                    // SAFETY: row oi + r of the target, c bytes from a column below n.
                    unsafe { store_u7x16(ptr.add((oi + r) * ld + oj + 16 * v), requant512(f[r][v], inv, zp), c) };
                }
            }
        }
        Dst::F32T { ptr, ld } => {
            // SAFETY: rows i0..i0 + rows and columns j0..j0 + cols are inside the output.
            unsafe { store_transposed512(&f, ptr, ld, oi, oj, rows, cols) };
        }
    }
}

/// Stores the tile transposed, `out[(j0 + c) * ld + i0 + r]`, 4 rows at a time: two rounds of
/// shuffles turn 4 row vectors into 16 columns of 4 (one per 128-bit lane), each stored with
/// a row mask.
///
/// # Safety
/// Rows `i0..i0 + rows` and columns `j0..j0 + cols` are inside the (transposed) output.
#[inline]
#[target_feature(enable = "avx512f,avx512vl")]
unsafe fn store_transposed512<const MR: usize, const NV: usize>(
    f: &[[__m512; NV]; MR],
    ptr: *mut f32,
    ld: usize,
    i0: usize,
    j0: usize,
    rows: usize,
    cols: usize,
) {
    for rb in (0..rows).step_by(4) {
        let mask = (1u8 << (rows - rb).min(4)) - 1;
        for v in 0..NV {
            let row = |i: usize| f[(rb + i).min(MR - 1)][v]; // rows past the tile are masked
            let (t0, t1) = (_mm512_unpacklo_ps(row(0), row(1)), _mm512_unpackhi_ps(row(0), row(1)));
            let (t2, t3) = (_mm512_unpacklo_ps(row(2), row(3)), _mm512_unpackhi_ps(row(2), row(3)));
            // Lane l of u[q] holds rows rb..rb + 4 of column 16v + 4l + q.
            let u = [
                _mm512_shuffle_ps::<0x44>(t0, t2),
                _mm512_shuffle_ps::<0xee>(t0, t2),
                _mm512_shuffle_ps::<0x44>(t1, t3),
                _mm512_shuffle_ps::<0xee>(t1, t3),
            ];
            for (q, &u) in u.iter().enumerate() {
                let lanes = [
                    _mm512_castps512_ps128(u),
                    _mm512_extractf32x4_ps::<1>(u),
                    _mm512_extractf32x4_ps::<2>(u),
                    _mm512_extractf32x4_ps::<3>(u),
                ];
                for (l, &x) in lanes.iter().enumerate() {
                    let c = 16 * v + 4 * l + q;
                    if c < cols {
                        // SAFETY: column j0 + c < n, rows rb.. below i0 + rows (mask).
                        unsafe { _mm_mask_storeu_ps(ptr.add((j0 + c) * ld + i0 + rb), mask, x) };
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// 256-bit: AVX-VNNI and AVX2 share the code (the dot product differs). Panels of up to 16
// columns (2 ymm); 16 ymm registers allow tiles of 6x2 (VNNI) or 4x2 (AVX2).
// ---------------------------------------------------------------------------------------

/// # Safety
/// As [`gemm_avx512`], for avx2 + avxvnni and [`super::Kernel::AvxVnni`].
#[target_feature(enable = "avx2,avxvnni")]
pub(super) unsafe fn gemm_avxvnni(job: &Job<'_>) {
    // SAFETY: forwarded; the features of the VNNI instantiation are enabled here.
    unsafe { gemm256::<true>(job) }
}

/// # Safety
/// As [`gemm_avx512`], for avx2 and [`super::Kernel::Avx2`].
#[target_feature(enable = "avx2")]
pub(super) unsafe fn gemm_avx2(job: &Job<'_>) {
    // SAFETY: forwarded; the AVX2 instantiation needs only avx2.
    unsafe { gemm256::<false>(job) }
}

// The generic 256-bit code is `inline(always)` without target features of its own: it is
// compiled inside `gemm_avxvnni` / `gemm_avx2`. (Enabling avxvnni on the AVX2 path would let
// LLVM fuse vpmaddwd + vpaddd into vpdpwssd.)

#[inline(always)]
unsafe fn gemm256<const VNNI: bool>(job: &Job<'_>) {
    let data = job.w.data().as_ptr();
    for (j0, pw, off) in job.w.panels() {
        // SAFETY: forwarded, as in `gemm_avx512`.
        unsafe {
            let panel = data.add(off);
            match (VNNI, pw / 8) {
                (true, 2) => panel256::<6, 2, VNNI>(job, panel, j0),
                (true, _) => panel256::<8, 1, VNNI>(job, panel, j0),
                (false, 2) => panel256::<4, 2, VNNI>(job, panel, j0),
                (false, _) => panel256::<6, 1, VNNI>(job, panel, j0),
            }
        }
    }
}

#[inline(always)]
unsafe fn panel256<const MR: usize, const NV: usize, const VNNI: bool>(job: &Job<'_>, panel: *const i8, j0: usize) {
    let mut blocks = RowBlocks::new(job, MR, 8 * NV);
    for ib in (0..job.m).step_by(blocks.rows) {
        let end = (ib + blocks.rows).min(job.m);
        let (dst, oi, oj) = blocks.target(job, ib, j0);
        // SAFETY: as in `panel512`.
        unsafe {
            for i0 in (ib..end).step_by(MR) {
                tile256::<MR, NV, VNNI>(job, panel, j0, i0, MR.min(end - i0), dst, oi + i0 - ib, oj);
            }
            blocks.flush(job, ib, end - ib, j0, (8 * NV).min(job.n - j0));
        }
    }
}

#[inline(always)]
unsafe fn step256<const MR: usize, const NV: usize, const VNNI: bool>(
    acc: &mut [[__m256i; NV]; MR],
    rows: &[*const u8; MR],
    off: usize,
    b: *const i8,
) {
    // SAFETY: as in `step512`; the caller enables avx2 (+ avxvnni when VNNI).
    unsafe {
        let mut bv = [_mm256_setzero_si256(); NV];
        for v in 0..NV {
            bv[v] = _mm256_loadu_si256(b.add(32 * v).cast());
        }
        for r in 0..MR {
            let x = _mm256_set1_epi32(rows[r].add(off).cast::<i32>().read_unaligned());
            for v in 0..NV {
                acc[r][v] = if VNNI {
                    _mm256_dpbusd_avx_epi32(acc[r][v], x, bv[v])
                } else {
                    let pairs = _mm256_maddubs_epi16(x, bv[v]);
                    _mm256_add_epi32(acc[r][v], _mm256_madd_epi16(pairs, _mm256_set1_epi16(1)))
                };
            }
        }
    }
}

/// [`requant512`] for 8 lanes.
#[inline(always)]
unsafe fn requant256(v: __m256, inv_scale: __m256, zp: __m256i) -> __m256i {
    // SAFETY: the caller enables avx2.
    unsafe {
        let t = _mm256_mul_ps(v, inv_scale);
        let t = _mm256_and_ps(t, _mm256_cmp_ps::<_CMP_ORD_Q>(t, t));
        let t = _mm256_min_ps(_mm256_max_ps(t, _mm256_set1_ps(-256.0)), _mm256_set1_ps(256.0));
        // cvtps rounds to nearest even (the MXCSR default, which Rust code never changes).
        let q = _mm256_add_epi32(_mm256_cvtps_epi32(t), zp);
        _mm256_min_epi32(_mm256_max_epi32(q, _mm256_setzero_si256()), _mm256_set1_epi32(127))
    }
}

/// 8 lanes in 0..=127 to 8 bytes.
#[inline(always)]
unsafe fn pack8(q: __m256i) -> [u8; 8] {
    // SAFETY: the caller enables avx2.
    unsafe {
        let p = _mm256_packs_epi32(q, q); // i16: [q0..3 q0..3 | q4..7 q4..7]
        let p = _mm256_packus_epi16(p, p); // u8: [q0..3 x4 | q4..7 x4]
        let lo = _mm_cvtsi128_si32(_mm256_castsi256_si128(p)) as u32;
        let hi = _mm_cvtsi128_si32(_mm256_extracti128_si256::<1>(p)) as u32;
        (u64::from(lo) | u64::from(hi) << 32).to_le_bytes()
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn tile256<const MR: usize, const NV: usize, const VNNI: bool>(
    job: &Job<'_>,
    panel: *const i8,
    j0: usize,
    i0: usize,
    rows: usize,
    dst: Dst,
    oi: usize,
    oj: usize,
) {
    let (k, pw) = (job.k, 8 * NV);
    // SAFETY: as in `tile512`; the caller enables avx2 (+ avxvnni).
    unsafe {
        let rowp = row_ptrs::<MR>(job, i0, rows);
        let mut acc = [[_mm256_setzero_si256(); NV]; MR];
        for g in 0..k / 4 {
            step256::<MR, NV, VNNI>(&mut acc, &rowp, 4 * g, panel.add(4 * pw * g));
        }
        if k % 4 != 0 {
            let tail = tail_words(&rowp, k);
            let tp = tail.each_ref().map(|t| t.as_ptr());
            step256::<MR, NV, VNNI>(&mut acc, &tp, 0, panel.add(4 * pw * (k / 4)));
        }

        let mut f = [[_mm256_setzero_ps(); NV]; MR];
        for v in 0..NV {
            let j = j0 + 8 * v;
            let zc = _mm256_loadu_si256(job.zc.as_ptr().add(j).cast());
            let scale = _mm256_loadu_ps(job.scale.as_ptr().add(j));
            for r in 0..MR {
                let mut y = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_sub_epi32(acc[r][v], zc)), scale);
                if let Some(b) = &job.bias {
                    y = _mm256_add_ps(y, _mm256_loadu_ps(b.as_ptr().add(j)));
                }
                if job.relu {
                    y = _mm256_max_ps(y, _mm256_setzero_ps());
                }
                f[r][v] = y;
            }
        }
        let cols = pw.min(job.n - j0);
        match dst {
            Dst::F32 { ptr, ld } => {
                for r in 0..rows {
                    for v in 0..NV {
                        let c = cols.saturating_sub(8 * v).min(8) as i32;
                        let to = ptr.add((oi + r) * ld + oj + 8 * v);
                        if c == 8 {
                            _mm256_storeu_ps(to, f[r][v]);
                        } else {
                            let mask =
                                _mm256_cmpgt_epi32(_mm256_set1_epi32(c), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
                            _mm256_maskstore_ps(to, mask, f[r][v]);
                        }
                    }
                }
            }
            Dst::U7 { ptr, ld, inv_scale, zp } => {
                let (inv, zp) = (_mm256_set1_ps(inv_scale), _mm256_set1_epi32(zp));
                for r in 0..rows {
                    for v in 0..NV {
                        let c = cols.saturating_sub(8 * v).min(8);
                        let bytes = pack8(requant256(f[r][v], inv, zp));
                        ptr::copy_nonoverlapping(bytes.as_ptr(), ptr.add((oi + r) * ld + oj + 8 * v), c);
                    }
                }
            }
            Dst::F32T { ptr, ld } => store_transposed256(&f, ptr, ld, oi, oj, rows, cols),
        }
    }
}

/// [`store_transposed512`] for 8 columns; partial row groups go through a copy (AVX masked
/// stores are slow on some cores).
#[inline(always)]
unsafe fn store_transposed256<const MR: usize, const NV: usize>(
    f: &[[__m256; NV]; MR],
    ptr: *mut f32,
    ld: usize,
    i0: usize,
    j0: usize,
    rows: usize,
    cols: usize,
) {
    // SAFETY: the caller enables avx2; stores as in `store_transposed512`.
    unsafe {
        for rb in (0..rows).step_by(4) {
            let g = (rows - rb).min(4);
            for v in 0..NV {
                let row = |i: usize| f[(rb + i).min(MR - 1)][v];
                let (t0, t1) = (_mm256_unpacklo_ps(row(0), row(1)), _mm256_unpackhi_ps(row(0), row(1)));
                let (t2, t3) = (_mm256_unpacklo_ps(row(2), row(3)), _mm256_unpackhi_ps(row(2), row(3)));
                let u = [
                    _mm256_shuffle_ps::<0x44>(t0, t2),
                    _mm256_shuffle_ps::<0xee>(t0, t2),
                    _mm256_shuffle_ps::<0x44>(t1, t3),
                    _mm256_shuffle_ps::<0xee>(t1, t3),
                ];
                for (q, &u) in u.iter().enumerate() {
                    for (l, x) in [_mm256_castps256_ps128(u), _mm256_extractf128_ps::<1>(u)].into_iter().enumerate() {
                        let c = 8 * v + 4 * l + q;
                        if c >= cols {
                            continue;
                        }
                        let dst = ptr.add((j0 + c) * ld + i0 + rb);
                        if g == 4 {
                            _mm_storeu_ps(dst, x);
                        } else {
                            let mut t = [0f32; 4];
                            _mm_storeu_ps(t.as_mut_ptr(), x);
                            ptr::copy_nonoverlapping(t.as_ptr(), dst, g);
                        }
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// Quantisation
// ---------------------------------------------------------------------------------------

/// Quantises with AVX-512 or AVX2; false if the CPU has neither (the caller then loops).
pub(super) fn quantize(x: &[f32], inv_scale: f32, zero_point: i32, out: &mut [u8]) -> bool {
    if is_x86_feature_detected!("avx512f") {
        // SAFETY: avx512f detected; `out` is as long as `x` (checked by the caller).
        unsafe { quantize512(x, inv_scale, zero_point, out) };
        true
    } else if is_x86_feature_detected!("avx2") {
        // SAFETY: avx2 detected; lengths as above.
        unsafe { quantize256(x, inv_scale, zero_point, out) };
        true
    } else {
        false
    }
}

#[target_feature(enable = "avx512f")]
unsafe fn quantize512(x: &[f32], inv_scale: f32, zero_point: i32, out: &mut [u8]) {
    let (inv, zp) = (_mm512_set1_ps(inv_scale), _mm512_set1_epi32(zero_point));
    for (xs, os) in x.chunks(16).zip(out.chunks_mut(16)) {
        // SAFETY: masked load of the chunk's `len` lanes (masked lanes never fault), `len`
        // bytes stored.
        unsafe {
            let q = requant512(_mm512_maskz_loadu_ps(mask16(xs.len()), xs.as_ptr()), inv, zp);
            store_u7x16(os.as_mut_ptr(), q, xs.len());
        }
    }
}

#[target_feature(enable = "avx2")]
unsafe fn quantize256(x: &[f32], inv_scale: f32, zero_point: i32, out: &mut [u8]) {
    let (inv, zp) = (_mm256_set1_ps(inv_scale), _mm256_set1_epi32(zero_point));
    let mut xs = x.chunks_exact(8);
    let mut os = out.chunks_exact_mut(8);
    for (xv, ov) in (&mut xs).zip(&mut os) {
        // SAFETY: 8 f32 in, 8 bytes out; avx2 enabled.
        unsafe { ov.copy_from_slice(&pack8(requant256(_mm256_loadu_ps(xv.as_ptr()), inv, zp))) };
    }
    for (o, &v) in os.into_remainder().iter_mut().zip(xs.remainder()) {
        *o = quantize_one(v, inv_scale, zero_point);
    }
}
