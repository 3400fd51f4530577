//! Portable kernel: plain loops the compiler may vectorise. It is what armv7 runs, and the
//! fallback everywhere else. It reads any packing; [`super::Kernel::Scalar`] packs row-major
//! `[k][n]` (one panel, groups of one), where the inner loop is a contiguous axpy.

use super::Job;

/// # Safety
/// `job` comes from [`super::qgemm`] (arguments checked, m >= 1).
pub(super) unsafe fn gemm(job: &Job<'_>) {
    let (data, layout, kp) = (job.w.data(), job.w.layout, job.w.kp);
    let mut acc = vec![0i32; layout.nr];
    for (j0, pw, off) in job.w.panels() {
        let panel = &data[off..off + kp * pw];
        let cols = pw.min(job.n - j0);
        for i in 0..job.m {
            // SAFETY: check_args proved (m - 1) * lda + k <= a.len().
            let row = unsafe { std::slice::from_raw_parts(job.a.add(i * job.lda), job.k) };
            let acc = &mut acc[..pw];
            acc.fill(0);
            if layout.kg == 1 {
                // Row-major weights: acc += a[i][kk] * w[kk][..], contiguous.
                for (&a, w_row) in row.iter().zip(panel.chunks_exact(pw)) {
                    let av = i32::from(a);
                    for (s, &wv) in acc.iter_mut().zip(w_row) {
                        *s = s.wrapping_add(av * i32::from(wv));
                    }
                }
            } else {
                for (g, group) in panel.chunks_exact(pw * layout.kg).enumerate() {
                    for t in 0..layout.kg.min(job.k.saturating_sub(g * layout.kg)) {
                        let av = i32::from(row[g * layout.kg + t]);
                        for (s, &wv) in acc.iter_mut().zip(group.iter().skip(t).step_by(layout.kg)) {
                            *s = s.wrapping_add(av * i32::from(wv));
                        }
                    }
                }
            }
            for (c, &s) in acc[..cols].iter().enumerate() {
                // SAFETY: i < m and j0 + c < n.
                unsafe { job.store(i, j0 + c, job.finish(s, j0 + c)) };
            }
        }
    }
}
