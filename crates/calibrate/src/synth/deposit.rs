//! Exact time-domain deposition: the instantaneous (true, analytic) TIF is accumulated along the
//! *executed* path in short time steps, at the true removal rate of that instant. Independent of
//! the calibration's FFT model on purpose (no dwell map, no convolution, no gridded TIF).

use ndarray::Array2;
use rayon::prelude::*;

use super::true_tif::TrueTif;
use crate::grid::MapGrid;

/// One instant of the executed path: position, duration, rate factor, spot scale.
#[derive(Debug, Clone, Copy)]
pub struct Instant {
    pub x_mm: f64,
    pub y_mm: f64,
    pub dt_s: f64,
    pub rate_factor: f64,
    pub scale: f64,
}

/// Removal (nm) on the grid: `sum_k dt_k f_k T((x - p_k) / s_k)`.
pub fn deposit(grid: &MapGrid, tif: &TrueTif, steps: &[Instant]) -> Array2<f64> {
    let (rows, cols) = (grid.rows, grid.cols);
    let chunk = (steps.len() / 16).max(1);
    steps
        .par_chunks(chunk)
        .map(|part| {
            let mut acc = vec![0.0; rows * cols];
            for s in part {
                let reach = tif.radius_mm * s.scale;
                let j0 = ((s.x_mm - reach - grid.x0_mm) / grid.dx_mm).ceil().max(0.0);
                let j1 = ((s.x_mm + reach - grid.x0_mm) / grid.dx_mm)
                    .floor()
                    .min(cols as f64 - 1.0);
                let i0 = ((s.y_mm - reach - grid.y0_mm) / grid.dy_mm).ceil().max(0.0);
                let i1 = ((s.y_mm + reach - grid.y0_mm) / grid.dy_mm)
                    .floor()
                    .min(rows as f64 - 1.0);
                if j1 < j0 || i1 < i0 {
                    continue;
                }
                let w = s.dt_s * s.rate_factor;
                for i in i0 as usize..=i1 as usize {
                    let y = grid.y_mm(i) - s.y_mm;
                    let row = &mut acc[i * cols..(i + 1) * cols];
                    for (j, a) in row
                        .iter_mut()
                        .enumerate()
                        .take(j1 as usize + 1)
                        .skip(j0 as usize)
                    {
                        *a += w * tif.rate(grid.x_mm(j) - s.x_mm, y, s.scale);
                    }
                }
            }
            acc
        })
        .reduce(
            || vec![0.0; rows * cols],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x += y;
                }
                a
            },
        )
        .pipe(|v| {
            Array2::from_shape_vec((rows, cols), v).unwrap_or_else(|_| Array2::zeros((rows, cols)))
        })
}

trait Pipe: Sized {
    fn pipe<R>(self, f: impl FnOnce(Self) -> R) -> R {
        f(self)
    }
}
impl<T> Pipe for T {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_dwell_at_one_point_leaves_the_spot() {
        let g = MapGrid {
            rows: 61,
            cols: 61,
            dx_mm: 0.5,
            dy_mm: 0.5,
            x0_mm: -15.0,
            y0_mm: -15.0,
        };
        let tif = TrueTif::default();
        let steps = vec![Instant {
            x_mm: 0.0,
            y_mm: 0.0,
            dt_s: 10.0,
            rate_factor: 1.0,
            scale: 1.0,
        }];
        let r = deposit(&g, &tif, &steps);
        assert!((r[(30, 30)] - 10.0 * tif.peak_nm_per_s).abs() < 1e-9);
        assert!((r[(30, 36)] - 10.0 * tif.rate(3.0, 0.0, 1.0)).abs() < 1e-9);
        // volume = dt * integral of the rate: compare with a fine quadrature
        let vol: f64 = r.sum() * 0.25;
        let mut q = 0.0;
        let h = 0.05;
        for a in -300..=300 {
            for b in -300..=300 {
                q += tif.rate(a as f64 * h, b as f64 * h, 1.0) * h * h;
            }
        }
        assert!((vol - 10.0 * q).abs() / vol < 1e-3);
    }
}
