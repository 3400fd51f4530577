//! Kernels of `ScatterElements` on row-major slices.

use crate::ops::{OpError, OpResult, check_len};

const OP: &str = "ScatterElements";

/// Row-major strides of `shape`.
fn strides(shape: &[usize]) -> Vec<usize> {
    let mut s = vec![1usize; shape.len()];
    for d in (0..shape.len().saturating_sub(1)).rev() {
        s[d] = s[d + 1] * shape[d + 1];
    }
    s
}

/// Checks shared by both kernels: ranks, lengths, the axis and that every non-axis
/// update dimension fits in the data's.
fn check(
    data_len: usize,
    data_shape: &[usize],
    indices_len: usize,
    updates_len: usize,
    updates_shape: &[usize],
    axis: usize,
) -> OpResult {
    let rank = data_shape.len();
    if rank == 0 || updates_shape.len() != rank || axis >= rank {
        return Err(OpError::Kernel {
            op: OP,
            message: format!("data rank {rank}, updates rank {}, axis {axis}", updates_shape.len()),
        });
    }
    check_len(OP, "data", data_len, data_shape.iter().product())?;
    let n: usize = updates_shape.iter().product();
    check_len(OP, "indices", indices_len, n)?;
    check_len(OP, "updates", updates_len, n)?;
    for d in (0..rank).filter(|&d| d != axis) {
        if updates_shape[d] > data_shape[d] {
            return Err(OpError::Kernel {
                op: OP,
                message: format!("updates dimension {d} is {}, data's is {}", updates_shape[d], data_shape[d]),
            });
        }
    }
    Ok(())
}

/// An index along an axis of length `len` (negative: from the end), or an error.
#[inline]
fn normalize(index: i64, len: usize) -> OpResult<usize> {
    let i = if index < 0 { index + len as i64 } else { index };
    crate::ops::checked_index(OP, i, len).map_err(|_| OpError::IndexOutOfRange { op: OP, index, len })
}

/// `data[c with c[axis] = indices[c]] = updates[c]` for every coordinate `c` of `updates`
/// (shape `updates_shape`, that of `indices` too), in row-major order, so the last of
/// several updates to one element wins. Nothing is written when an index is out of
/// range (all are checked first).
pub fn scatter_elements<T: Copy>(
    data: &mut [T],
    data_shape: &[usize],
    indices: &[i64],
    updates: &[T],
    updates_shape: &[usize],
    axis: usize,
) -> OpResult {
    check(data.len(), data_shape, indices.len(), updates.len(), updates_shape, axis)?;
    let len = data_shape[axis];
    for &i in indices {
        normalize(i, len)?;
    }
    if updates.is_empty() {
        return Ok(());
    }
    let rank = data_shape.len();
    let ds = strides(data_shape);
    let last = rank - 1;
    let inner = updates_shape[last];
    let axis_stride = ds[axis];
    // Odometer over every dimension but the last; the last runs in the inner loop.
    let mut coord = vec![0usize; last];
    for (row, (idx_row, upd_row)) in indices.chunks_exact(inner).zip(updates.chunks_exact(inner)).enumerate() {
        if row > 0 {
            for d in (0..last).rev() {
                coord[d] += 1;
                if coord[d] < updates_shape[d] {
                    break;
                }
                coord[d] = 0;
            }
        }
        let base: usize = (0..last).filter(|&d| d != axis).map(|d| coord[d] * ds[d]).sum();
        if axis == last {
            for (&i, &u) in idx_row.iter().zip(upd_row) {
                let i = if i < 0 { (i + len as i64) as usize } else { i as usize };
                data[base + i] = u;
            }
        } else {
            for (j, (&i, &u)) in idx_row.iter().zip(upd_row).enumerate() {
                let i = if i < 0 { (i + len as i64) as usize } else { i as usize };
                data[base + j + i * axis_stride] = u;
            }
        }
    }
    Ok(())
}

/// The reference: one update at a time, its full coordinate decoded from the flat index.
pub fn scatter_elements_reference<T: Copy>(
    data: &[T],
    data_shape: &[usize],
    indices: &[i64],
    updates: &[T],
    updates_shape: &[usize],
    axis: usize,
) -> OpResult<Vec<T>> {
    check(data.len(), data_shape, indices.len(), updates.len(), updates_shape, axis)?;
    let mut out = data.to_vec();
    let (ds, us) = (strides(data_shape), strides(updates_shape));
    for (flat, (&index, &u)) in indices.iter().zip(updates).enumerate() {
        let mut offset = 0;
        for d in 0..data_shape.len() {
            let c = (flat / us[d]) % updates_shape[d];
            let c = if d == axis { normalize(index, data_shape[axis])? } else { c };
            offset += c * ds[d];
        }
        out[offset] = u;
    }
    Ok(out)
}

/// `data[indices[r]] = updates[r]` for whole rows along axis 0 (row `r` of `updates`,
/// shape `updates_shape`, over the row of `data`, shape `data_shape`, that its index
/// names); `indices` holds one index per update row, or a single one for all (the
/// broadcast an `Expand` of a length-1 index gives). Negative indices count from the end;
/// the last of several updates to one row wins. The same as [`scatter_elements`] along
/// axis 0 with the indices broadcast over each row, without them; nothing is written when
/// an index is out of range.
pub fn scatter_rows<T: Copy>(
    data: &mut [T],
    data_shape: &[usize],
    indices: &[i64],
    updates: &[T],
    updates_shape: &[usize],
) -> OpResult {
    const OP: &str = "ScatterRows";
    let (Some((&rows, row_dims)), Some((&n, update_row_dims))) =
        (data_shape.split_first(), updates_shape.split_first())
    else {
        return Err(OpError::Kernel { op: OP, message: "data and updates need a row axis".into() });
    };
    if row_dims != update_row_dims {
        return Err(OpError::Kernel {
            op: OP,
            message: format!("data rows are {row_dims:?}, update rows {update_row_dims:?}"),
        });
    }
    let row_len: usize = row_dims.iter().product();
    check_len(OP, "data", data.len(), rows * row_len)?;
    check_len(OP, "updates", updates.len(), n * row_len)?;
    if n == 0 {
        return Ok(());
    }
    if !(indices.len() == n || indices.len() == 1) {
        return Err(OpError::Kernel { op: OP, message: format!("{} indices for {n} update rows", indices.len()) });
    }
    let mut targets = Vec::with_capacity(indices.len());
    for &i in indices {
        let k = if i < 0 { i + rows as i64 } else { i };
        targets.push(crate::ops::checked_index(OP, k, rows).map_err(|_| OpError::IndexOutOfRange {
            op: OP,
            index: i,
            len: rows,
        })?);
    }
    if row_len == 0 {
        return Ok(());
    }
    for (r, update) in updates.chunks_exact(row_len).enumerate() {
        let t = targets[if targets.len() == 1 { 0 } else { r }];
        data[t * row_len..(t + 1) * row_len].copy_from_slice(update);
    }
    Ok(())
}
