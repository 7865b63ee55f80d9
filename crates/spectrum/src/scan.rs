//! The two streaming passes every line analysis starts with, so that no later pass has to look
//! at a whole line twice:
//!
//! - `MaskSummary`: valid pixels per row, the first / last valid column of each row and the
//!   invalid pixels per column (one read of the mask). A line with no invalid pixel takes the
//!   dense fast path; the others keep the segment rules of `lines`.
//! - `HeightSums`: per row sum(z), sum(z u), sum(z u^2) in the normalised x coordinate u of the
//!   form fit, and per column sum(z) (one read of the heights). They feed the piston / tilt /
//!   power fit and give every fully valid line its mean without another pass.
//!
//! Invalid pixels store 0 (the `Surface` invariant), so the height sums need no mask. Rows are
//! reduced in fixed bands whose partial sums are added in band order: the results do not depend
//! on the number of threads.

use ndarray::ArrayView2;
use rayon::prelude::*;

/// Rows per band of the parallel reductions.
const BAND_ROWS: usize = 64;

/// One band's rows (valid count, first / last valid column) and, when one of its rows has an
/// invalid pixel, its invalid count per column.
type BandMask = (Vec<(usize, Option<(usize, usize)>)>, Option<Vec<usize>>);

/// Where the valid pixels are.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct MaskSummary {
    pub cols: usize,
    /// Valid pixels in each row.
    pub row_valid: Vec<usize>,
    /// First and last valid column of each row (`None` for an empty row).
    pub row_span: Vec<Option<(usize, usize)>>,
    /// Invalid pixels in each column.
    pub col_invalid: Vec<usize>,
}

impl MaskSummary {
    pub fn of(valid: ArrayView2<bool>) -> Self {
        let (rows, cols) = valid.dim();
        let bands: Vec<BandMask> = (0..rows.div_ceil(BAND_ROWS))
            .into_par_iter()
            .map(|b| {
                let mut per_row = Vec::with_capacity(BAND_ROWS);
                let mut col_invalid: Option<Vec<usize>> = None;
                for i in b * BAND_ROWS..((b + 1) * BAND_ROWS).min(rows) {
                    let row = valid.row(i);
                    let count = match row.as_slice() {
                        Some(r) => r.iter().map(|&v| v as usize).sum(),
                        None => row.iter().filter(|&&v| v).count(),
                    };
                    if count == cols {
                        per_row.push((count, (cols > 0).then(|| (0, cols - 1))));
                        continue;
                    }
                    let ci = col_invalid.get_or_insert_with(|| vec![0; cols]);
                    for (c, &ok) in ci.iter_mut().zip(row.iter()) {
                        *c += !ok as usize;
                    }
                    let first = row.iter().position(|&v| v);
                    let last = row.iter().rposition(|&v| v);
                    per_row.push((count, first.zip(last)));
                }
                (per_row, col_invalid)
            })
            .collect();
        let mut s = MaskSummary {
            cols,
            row_valid: Vec::with_capacity(rows),
            row_span: Vec::with_capacity(rows),
            col_invalid: vec![0; cols],
        };
        for (per_row, ci) in bands {
            for (count, span) in per_row {
                s.row_valid.push(count);
                s.row_span.push(span);
            }
            if let Some(ci) = ci {
                for (a, b) in s.col_invalid.iter_mut().zip(ci) {
                    *a += b;
                }
            }
        }
        s
    }

    pub fn row_full(&self, i: usize) -> bool {
        self.row_valid[i] == self.cols
    }

    pub fn col_full(&self, j: usize) -> bool {
        self.col_invalid[j] == 0
    }

    pub fn valid_count(&self) -> usize {
        self.row_valid.iter().sum()
    }

    /// (first row, last row, first column, last column) holding a valid pixel.
    pub fn bounding_box(&self) -> Option<(usize, usize, usize, usize)> {
        let (mut r0, mut r1, mut c0, mut c1) = (usize::MAX, 0usize, usize::MAX, 0usize);
        for (i, span) in self.row_span.iter().enumerate() {
            if let Some((a, b)) = span {
                r0 = r0.min(i);
                r1 = r1.max(i);
                c0 = c0.min(*a);
                c1 = c1.max(*b);
            }
        }
        (r0 != usize::MAX).then_some((r0, r1, c0, c1))
    }
}

/// Height sums of one pass over the map.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct HeightSums {
    /// Per row: [sum z, sum z u, sum z u^2] (the u moments are 0 when no `us` was given).
    pub row: Vec<[f64; 3]>,
    /// Per column: sum z over all rows.
    pub col: Vec<f64>,
}

impl HeightSums {
    /// `us`: the normalised x coordinate of every column, or empty when only plain sums are
    /// needed; `second`: whether sum(z u^2) is needed (a power term).
    pub fn of(heights: ArrayView2<f64>, us: &[f64], second: bool) -> Self {
        let (rows, cols) = heights.dim();
        let moments = us.len() == cols && cols > 0;
        let u2: Vec<f64> = if moments && second {
            us.iter().map(|u| u * u).collect()
        } else {
            Vec::new()
        };
        let bands: Vec<(Vec<[f64; 3]>, Vec<f64>)> = (0..rows.div_ceil(BAND_ROWS))
            .into_par_iter()
            .map(|b| {
                let mut per_row = Vec::with_capacity(BAND_ROWS);
                let mut col = vec![0.0; cols];
                for i in b * BAND_ROWS..((b + 1) * BAND_ROWS).min(rows) {
                    let row = heights.row(i);
                    let r = match row.as_slice() {
                        Some(r) => std::borrow::Cow::Borrowed(r),
                        None => std::borrow::Cow::Owned(row.to_vec()),
                    };
                    per_row.push(if moments {
                        row_moments(&r, us, &u2, &mut col)
                    } else {
                        [row_sum(&r, &mut col), 0.0, 0.0]
                    });
                }
                (per_row, col)
            })
            .collect();
        let mut out = HeightSums {
            row: Vec::with_capacity(rows),
            col: vec![0.0; cols],
        };
        for (per_row, col) in bands {
            out.row.extend(per_row);
            for (a, b) in out.col.iter_mut().zip(col) {
                *a += b;
            }
        }
        out
    }
}

/// sum z of one row, adding the row into the column sums (four lanes, as `row_moments`).
fn row_sum(z: &[f64], col: &mut [f64]) -> f64 {
    avx2_or_baseline!(row_sum_impl(z, col))
}

#[inline(always)]
fn row_sum_impl(z: &[f64], col: &mut [f64]) -> f64 {
    let mut s = [0.0f64; 4];
    let n4 = z.len() / 4 * 4;
    for (zc, cc) in z[..n4].chunks_exact(4).zip(col[..n4].chunks_exact_mut(4)) {
        for l in 0..4 {
            s[l] += zc[l];
            cc[l] += zc[l];
        }
    }
    let mut out = (s[0] + s[1]) + (s[2] + s[3]);
    for k in n4..z.len() {
        out += z[k];
        col[k] += z[k];
    }
    out
}

/// sum z, sum z u, sum z u^2 (0 when `u2` is empty) of one row, adding the row into the
/// column sums: three short loops over the row (cached after the first) vectorise better than
/// one loop with four accumulators.
fn row_moments(z: &[f64], us: &[f64], u2: &[f64], col: &mut [f64]) -> [f64; 3] {
    let s0 = row_sum(z, col);
    let s1 = dot(z, us);
    let s2 = if u2.is_empty() { 0.0 } else { dot(z, u2) };
    [s0, s1, s2]
}

/// sum a[k] b[k] in four lanes.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    avx2_or_baseline!(dot_impl(a, b))
}

#[inline(always)]
fn dot_impl(a: &[f64], b: &[f64]) -> f64 {
    let mut s = [0.0f64; 4];
    let n4 = a.len().min(b.len()) / 4 * 4;
    for (ac, bc) in a[..n4].chunks_exact(4).zip(b[..n4].chunks_exact(4)) {
        for l in 0..4 {
            s[l] += ac[l] * bc[l];
        }
    }
    let mut out = (s[0] + s[1]) + (s[2] + s[3]);
    for k in n4..a.len().min(b.len()) {
        out += a[k] * b[k];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn summaries_match_brute_force() {
        let (rows, cols) = (150, 37);
        let h = Array2::from_shape_fn((rows, cols), |(i, j)| ((i * 31 + j * 17) % 23) as f64 - 9.5);
        let mut v = Array2::from_elem((rows, cols), true);
        v[(3, 0)] = false;
        v[(3, 36)] = false;
        v[(70, 5)] = false;
        for j in 0..cols {
            v[(149, j)] = false;
        }
        let m = MaskSummary::of(v.view());
        assert_eq!(m.row_valid[3], cols - 2);
        assert_eq!(m.row_span[3], Some((1, 35)));
        assert_eq!(m.row_span[149], None);
        assert_eq!(m.col_invalid[5], 2);
        assert_eq!(m.col_invalid[6], 1);
        assert!(m.row_full(0) && !m.row_full(70) && !m.col_full(0));
        assert_eq!(m.valid_count(), v.iter().filter(|&&b| b).count());
        assert_eq!(m.bounding_box(), Some((0, 148, 0, 36)));

        let us: Vec<f64> = (0..cols).map(|j| (j as f64 - 18.0) / 18.0).collect();
        let s = HeightSums::of(h.view(), &us, true);
        for i in [0, 63, 64, 149] {
            let e0: f64 = h.row(i).sum();
            let e1: f64 = h.row(i).iter().zip(&us).map(|(z, u)| z * u).sum();
            let e2: f64 = h.row(i).iter().zip(&us).map(|(z, u)| z * u * u).sum();
            assert!((s.row[i][0] - e0).abs() < 1e-9);
            assert!((s.row[i][1] - e1).abs() < 1e-9);
            assert!((s.row[i][2] - e2).abs() < 1e-9);
        }
        for j in [0, 20, 36] {
            assert!((s.col[j] - h.column(j).sum()).abs() < 1e-9);
        }
        // A transposed (column-major) view gives the same sums.
        let ht = h.t().to_owned();
        let st = HeightSums::of(ht.t(), &[], false);
        assert_eq!(st.row.len(), rows);
        assert!((st.row[5][0] - s.row[5][0]).abs() < 1e-9);
    }
}
