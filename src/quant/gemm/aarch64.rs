//! aarch64 kernels: NEON dot product (`sdot`) and baseline NEON.
//!
//! Both read panels packed `[kp / 4][pw][4]`: one 16-byte vector holds the 4 weights of a
//! k-group for 4 columns. Activations (u7) are valid signed bytes, so the signed
//! instructions compute the exact products.
//!
//! * `sdot` (Armv8.2 dotprod): `vdotq_s32` is unstable in Rust 1.95, so the instruction is
//!   written with `asm!` (by-element form: 16 activation bytes = 4 k-groups of one row are
//!   loaded once and each group is used as a broadcast lane). Tiles of 8x1, 8x2, 4x3, 4x4
//!   vectors over panels of 16 columns; k is padded to 16.
//! * baseline: `smull` + `smlal` of two k-groups into i16 (|sum| <= 2 * 127 * 128, no
//!   overflow) then `sadalp` into i32 pairs, reduced with `addp` at the end. Tiles of 4 rows
//!   x 8 columns (2 x 2 i32 accumulators per 4 columns); k padded to 8.
//!
//! Tails: as on x86 (repeated last row, zero-padded k-tail copy, masked stores).

// Register tiles are indexed by (row, vector): ranges read better than iterator chains here.
#![allow(clippy::needless_range_loop)]

use std::arch::aarch64::*;
use std::arch::asm;
use std::ptr;

use super::{Dst, Job, RowBlocks, quantize_one, row_ptrs};

/// The output stage of 4 lanes: the scalar operations, lane by lane.
#[inline(always)]
unsafe fn finish4(job: &Job<'_>, acc: int32x4_t, j: usize) -> float32x4_t {
    // SAFETY: j + 4 <= n_pad, the length of zc, scale and bias; neon is baseline on aarch64.
    unsafe {
        let c = vsubq_s32(acc, vld1q_s32(job.zc.as_ptr().add(j)));
        let mut y = vmulq_f32(vcvtq_f32_s32(c), vld1q_f32(job.scale.as_ptr().add(j)));
        if let Some(b) = &job.bias {
            y = vaddq_f32(y, vld1q_f32(b.as_ptr().add(j)));
        }
        if job.relu {
            let zero = vdupq_n_f32(0.0);
            y = vbslq_f32(vcgtq_f32(y, zero), y, zero); // v > 0 ? v : +0 (NaN -> +0)
        }
        y
    }
}

/// u7 requantisation of 4 lanes as `quantize_one`: the clamp to ±256 keeps NaN (fmax/fmin
/// propagate it) and `fcvtns` rounds to nearest even, giving 0 for NaN.
#[inline(always)]
unsafe fn requant4(v: float32x4_t, inv_scale: f32, zp: i32) -> [u8; 4] {
    // SAFETY: neon is baseline on aarch64.
    unsafe {
        let t = vmulq_f32(v, vdupq_n_f32(inv_scale));
        let t = vminq_f32(vmaxq_f32(t, vdupq_n_f32(-256.0)), vdupq_n_f32(256.0));
        let q = vaddq_s32(vcvtnq_s32_f32(t), vdupq_n_s32(zp));
        let q = vminq_s32(vmaxq_s32(q, vdupq_n_s32(0)), vdupq_n_s32(127));
        let b = vqmovun_s16(vcombine_s16(vmovn_s32(q), vmovn_s32(q)));
        vget_lane_u32::<0>(vreinterpret_u32_u8(b)).to_le_bytes()
    }
}

/// Stores the finished register tile `f` (MR rows x NV vectors of 4 columns) into `dst`,
/// its (row 0, column 0) at output (oi, oj).
///
/// # Safety
/// `dst` holds rows `oi..oi + rows` and columns `oj..oj + cols` (columns below n).
#[inline(always)]
unsafe fn store<const MR: usize, const NV: usize>(
    f: &[[float32x4_t; NV]; MR],
    dst: Dst,
    oi: usize,
    oj: usize,
    rows: usize,
    cols: usize,
) {
    // SAFETY: forwarded; every store stays below (oi + rows, oj + cols).
    unsafe {
        match dst {
            Dst::F32 { ptr, ld } => {
                for r in 0..rows {
                    for v in 0..NV {
                        let c = cols.saturating_sub(4 * v).min(4);
                        let to = ptr.add((oi + r) * ld + oj + 4 * v);
                        if c == 4 {
                            vst1q_f32(to, f[r][v]);
                        } else {
                            let mut t = [0f32; 4];
                            vst1q_f32(t.as_mut_ptr(), f[r][v]);
                            ptr::copy_nonoverlapping(t.as_ptr(), to, c);
                        }
                    }
                }
            }
            Dst::U7 { ptr, ld, inv_scale, zp } => {
                for r in 0..rows {
                    for v in 0..NV {
                        let c = cols.saturating_sub(4 * v).min(4);
                        let q = requant4(f[r][v], inv_scale, zp);
                        ptr::copy_nonoverlapping(q.as_ptr(), ptr.add((oi + r) * ld + oj + 4 * v), c);
                    }
                }
            }
            Dst::F32T { ptr, ld } => {
                // 4 rows at a time: a 4x4 transpose per vector gives columns of 4 rows.
                for rb in (0..rows).step_by(4) {
                    let g = (rows - rb).min(4);
                    for v in 0..NV {
                        let row = |i: usize| f[(rb + i).min(MR - 1)][v]; // rows past the tile unused
                        let (t01, t23) = (vtrnq_f32(row(0), row(1)), vtrnq_f32(row(2), row(3)));
                        let columns = [
                            vcombine_f32(vget_low_f32(t01.0), vget_low_f32(t23.0)),
                            vcombine_f32(vget_low_f32(t01.1), vget_low_f32(t23.1)),
                            vcombine_f32(vget_high_f32(t01.0), vget_high_f32(t23.0)),
                            vcombine_f32(vget_high_f32(t01.1), vget_high_f32(t23.1)),
                        ];
                        for (q, &x) in columns.iter().enumerate().take(cols.saturating_sub(4 * v)) {
                            let to = ptr.add((oj + 4 * v + q) * ld + oi + rb);
                            if g == 4 {
                                vst1q_f32(to, x);
                            } else {
                                let mut t = [0f32; 4];
                                vst1q_f32(t.as_mut_ptr(), x);
                                ptr::copy_nonoverlapping(t.as_ptr(), to, g);
                            }
                        }
                    }
                }
            }
        }
    }
}

/// `kq` activation bytes of each row from byte `off`, zero-padded past k (the k tail).
#[inline(always)]
unsafe fn padded_rows<const MR: usize, const KQ: usize>(
    rows: &[*const u8; MR],
    off: usize,
    k: usize,
) -> [[u8; KQ]; MR] {
    let mut t = [[0u8; KQ]; MR];
    for r in 0..MR {
        for i in 0..KQ {
            if off + i < k {
                // SAFETY: a byte below k of a row of k bytes.
                t[r][i] = unsafe { *rows[r].add(off + i) };
            }
        }
    }
    t
}

// ---------------------------------------------------------------------------------------
// sdot
// ---------------------------------------------------------------------------------------

/// `acc += sdot(b, a.4b[lane])`: each i32 lane of `acc` gets the 4-byte dot product of its
/// 4 bytes of `b` with bytes `4 * lane..4 * lane + 4` of `a`.
macro_rules! sdot_lane {
    ($acc:expr, $b:expr, $a:expr, $lane:literal) => {
        // SAFETY: register-only instruction; the enclosing function enables dotprod.
        unsafe {
            asm!(
                concat!("sdot {acc:v}.4s, {b:v}.16b, {a:v}.4b[", $lane, "]"),
                acc = inout(vreg) $acc,
                b = in(vreg) $b,
                a = in(vreg) $a,
                options(pure, nomem, nostack, preserves_flags)
            )
        }
    };
}

/// # Safety
/// `job` comes from `qgemm` (checked), the CPU has dotprod, and the weights are packed for
/// [`super::Kernel::NeonDot`].
#[target_feature(enable = "neon,dotprod")]
pub(super) unsafe fn gemm_dot(job: &Job<'_>) {
    let data = job.w.data().as_ptr();
    for (j0, pw, off) in job.w.panels() {
        // SAFETY (each arm): the panel lies inside the packed data and is 4 * NV wide.
        let panel = unsafe { data.add(off) };
        match pw / 4 {
            4 => unsafe { panel_dot::<4, 4>(job, panel, j0) },
            3 => unsafe { panel_dot::<4, 3>(job, panel, j0) },
            2 => unsafe { panel_dot::<8, 2>(job, panel, j0) },
            _ => unsafe { panel_dot::<8, 1>(job, panel, j0) },
        }
    }
}

#[inline]
#[target_feature(enable = "neon,dotprod")]
unsafe fn panel_dot<const MR: usize, const NV: usize>(job: &Job<'_>, panel: *const i8, j0: usize) {
    let mut blocks = RowBlocks::new(job, MR, 4 * NV);
    for ib in (0..job.m).step_by(blocks.rows) {
        let end = (ib + blocks.rows).min(job.m);
        let (dst, oi, oj) = blocks.target(job, ib, j0);
        // SAFETY: forwarded; 1 <= rows <= end - i0; the target holds the block, whose rows
        // and columns are inside the output.
        unsafe {
            for i0 in (ib..end).step_by(MR) {
                tile_dot::<MR, NV>(job, panel, j0, i0, MR.min(end - i0), dst, oi + i0 - ib, oj);
            }
            blocks.flush(job, ib, end - ib, j0, (4 * NV).min(job.n - j0));
        }
    }
}

/// 16 k values (4 groups): `a[r]` holds them for row r, `b` points at group 0 of the block.
#[inline]
#[target_feature(enable = "neon,dotprod")]
unsafe fn step_dot<const MR: usize, const NV: usize>(
    acc: &mut [[int32x4_t; NV]; MR],
    a: &[int8x16_t; MR],
    b: *const i8,
) {
    let pw = 4 * NV;
    macro_rules! group {
        ($g:literal) => {
            for v in 0..NV {
                // SAFETY: group g of the 4-group block, columns 4v..4v + 4 of the panel.
                let bv = unsafe { vld1q_s8(b.add(($g * pw + 4 * v) * 4)) };
                for r in 0..MR {
                    sdot_lane!(acc[r][v], bv, a[r], $g);
                }
            }
        };
    }
    group!(0);
    group!(1);
    group!(2);
    group!(3);
}

#[inline]
#[target_feature(enable = "neon,dotprod")]
#[allow(clippy::too_many_arguments)]
unsafe fn tile_dot<const MR: usize, const NV: usize>(
    job: &Job<'_>,
    panel: *const i8,
    j0: usize,
    i0: usize,
    rows: usize,
    dst: Dst,
    oi: usize,
    oj: usize,
) {
    let (k, pw) = (job.k, 4 * NV);
    // SAFETY: rows i0..i0 + rows exist; blocks of 16 k below k are read from the rows, the
    // tail from a padded copy; the panel holds kp = k rounded up to 16.
    unsafe {
        let rowp = row_ptrs::<MR>(job, i0, rows);
        let mut acc = [[vdupq_n_s32(0); NV]; MR];
        let mut a = [vdupq_n_s8(0); MR];
        for s in 0..k / 16 {
            for r in 0..MR {
                a[r] = vld1q_s8(rowp[r].add(16 * s).cast());
            }
            step_dot(&mut acc, &a, panel.add(16 * pw * s));
        }
        if k % 16 != 0 {
            let t = padded_rows::<MR, 16>(&rowp, k / 16 * 16, k);
            for r in 0..MR {
                a[r] = vld1q_s8(t[r].as_ptr().cast());
            }
            step_dot(&mut acc, &a, panel.add(16 * pw * (k / 16)));
        }
        let mut f = [[vdupq_n_f32(0.0); NV]; MR];
        for r in 0..MR {
            for v in 0..NV {
                f[r][v] = finish4(job, acc[r][v], j0 + 4 * v);
            }
        }
        store(&f, dst, oi, oj, rows, pw.min(job.n - j0));
    }
}

// ---------------------------------------------------------------------------------------
// Baseline NEON
// ---------------------------------------------------------------------------------------

/// # Safety
/// As [`gemm_dot`], for [`super::Kernel::Neon`] (no dotprod needed).
#[target_feature(enable = "neon")]
pub(super) unsafe fn gemm_neon(job: &Job<'_>) {
    let data = job.w.data().as_ptr();
    for (j0, pw, off) in job.w.panels() {
        // SAFETY (each arm): the panel lies inside the packed data and is 4 * NV wide.
        let panel = unsafe { data.add(off) };
        match pw / 4 {
            2 => unsafe { panel_neon::<4, 2>(job, panel, j0) },
            _ => unsafe { panel_neon::<6, 1>(job, panel, j0) },
        }
    }
}

#[inline]
#[target_feature(enable = "neon")]
unsafe fn panel_neon<const MR: usize, const NV: usize>(job: &Job<'_>, panel: *const i8, j0: usize) {
    let mut blocks = RowBlocks::new(job, MR, 4 * NV);
    for ib in (0..job.m).step_by(blocks.rows) {
        let end = (ib + blocks.rows).min(job.m);
        let (dst, oi, oj) = blocks.target(job, ib, j0);
        // SAFETY: forwarded; 1 <= rows <= end - i0; the target holds the block, whose rows
        // and columns are inside the output.
        unsafe {
            for i0 in (ib..end).step_by(MR) {
                tile_neon::<MR, NV>(job, panel, j0, i0, MR.min(end - i0), dst, oi + i0 - ib, oj);
            }
            blocks.flush(job, ib, end - ib, j0, (4 * NV).min(job.n - j0));
        }
    }
}

/// 8 k values (2 groups) of each row (`a[r]`), against the 2-group block at `b`.
/// `acc[r][v]` = (pairs of columns 0-1, pairs of columns 2-3) of vector v.
#[inline]
#[target_feature(enable = "neon")]
unsafe fn step_neon<const MR: usize, const NV: usize>(
    acc: &mut [[[int32x4_t; 2]; NV]; MR],
    a: &[int8x8_t; MR],
    b: *const i8,
) {
    let pw = 4 * NV;
    for v in 0..NV {
        // SAFETY: groups 0 and 1 of the block, columns 4v..4v + 4 of the panel.
        let (b0, b1) = unsafe { (vld1q_s8(b.add(16 * v)), vld1q_s8(b.add(4 * pw + 16 * v))) };
        for r in 0..MR {
            let a32 = vreinterpret_s32_s8(a[r]);
            let a0 = vreinterpret_s8_s32(vdup_lane_s32::<0>(a32)); // group 0, twice
            let a1 = vreinterpret_s8_s32(vdup_lane_s32::<1>(a32)); // group 1, twice
            let lo = vmlal_s8(vmull_s8(a0, vget_low_s8(b0)), a1, vget_low_s8(b1));
            let hi = vmlal_s8(vmull_s8(a0, vget_high_s8(b0)), a1, vget_high_s8(b1));
            acc[r][v][0] = vpadalq_s16(acc[r][v][0], lo);
            acc[r][v][1] = vpadalq_s16(acc[r][v][1], hi);
        }
    }
}

#[inline]
#[target_feature(enable = "neon")]
#[allow(clippy::too_many_arguments)]
unsafe fn tile_neon<const MR: usize, const NV: usize>(
    job: &Job<'_>,
    panel: *const i8,
    j0: usize,
    i0: usize,
    rows: usize,
    dst: Dst,
    oi: usize,
    oj: usize,
) {
    let (k, pw) = (job.k, 4 * NV);
    // SAFETY: as in `tile_dot`, with blocks of 8 k (the panel holds k rounded up to 8).
    unsafe {
        let rowp = row_ptrs::<MR>(job, i0, rows);
        let mut acc = [[[vdupq_n_s32(0); 2]; NV]; MR];
        let mut a = [vdup_n_s8(0); MR];
        for s in 0..k / 8 {
            for r in 0..MR {
                a[r] = vld1_s8(rowp[r].add(8 * s).cast());
            }
            step_neon(&mut acc, &a, panel.add(8 * pw * s));
        }
        if k % 8 != 0 {
            let t = padded_rows::<MR, 8>(&rowp, k / 8 * 8, k);
            for r in 0..MR {
                a[r] = vld1_s8(t[r].as_ptr().cast());
            }
            step_neon(&mut acc, &a, panel.add(8 * pw * (k / 8)));
        }
        let mut f = [[vdupq_n_f32(0.0); NV]; MR];
        for r in 0..MR {
            for v in 0..NV {
                let c = vpaddq_s32(acc[r][v][0], acc[r][v][1]); // columns 0, 1, 2, 3
                f[r][v] = finish4(job, c, j0 + 4 * v);
            }
        }
        store(&f, dst, oi, oj, rows, pw.min(job.n - j0));
    }
}

// ---------------------------------------------------------------------------------------
// Quantisation
// ---------------------------------------------------------------------------------------

/// NEON quantisation (`out` as long as `x`, checked by the caller).
pub(super) fn quantize(x: &[f32], inv_scale: f32, zero_point: i32, out: &mut [u8]) {
    let mut xs = x.chunks_exact(4);
    let mut os = out.chunks_exact_mut(4);
    for (xv, ov) in (&mut xs).zip(&mut os) {
        // SAFETY: 4 f32 read; neon is baseline on aarch64.
        ov.copy_from_slice(&unsafe { requant4(vld1q_f32(xv.as_ptr()), inv_scale, zero_point) });
    }
    for (o, &v) in os.into_remainder().iter_mut().zip(xs.remainder()) {
        *o = quantize_one(v, inv_scale, zero_point);
    }
}
