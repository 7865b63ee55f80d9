//! Weighted dwell maps: every coupling sample's dwell dt, times a weight per channel (1, u, u²,
//! δ, δ², ...), spread over the grid with 4 x 4 Keys cubic-convolution weights (a = −1/2).
//!
//! The cubic splat keeps a sample's mass, centroid and second moment, so splat + convolution
//! with the sampled kernel differs from the continuous deposition only at fourth order in the
//! pixel size (the same choice as bonnetlab_process's fast removal; this is a streaming,
//! multi-channel copy so 3.6 million samples are splatted once for all channels).

use bonnetlab_process::Grid;

/// Keys weights for taps at −1, 0, 1, 2 around fraction f in [0, 1).
pub fn keys_weights(f: f64) -> [f64; 4] {
    let w = |t: f64| {
        let t = t.abs();
        if t <= 1.0 {
            (1.5 * t - 2.5) * t * t + 1.0
        } else if t < 2.0 {
            ((-0.5 * t + 2.5) * t - 4.0) * t + 2.0
        } else {
            0.0
        }
    };
    [w(1.0 + f), w(f), w(1.0 - f), w(2.0 - f)]
}

/// `NC` dwell maps (s per pixel, weighted) on one grid, interleaved per pixel.
#[derive(Debug, Clone)]
pub struct DwellChannels<const NC: usize> {
    pub grid: Grid,
    pub data: Vec<[f64; NC]>,
}

impl<const NC: usize> DwellChannels<NC> {
    pub fn new(grid: Grid) -> Self {
        DwellChannels {
            grid,
            data: vec![[0.0; NC]; grid.rows * grid.cols],
        }
    }

    /// Adds dt · w[c] at (x, y) mm to every channel c; points beyond the grid are dropped.
    pub fn add(&mut self, x_mm: f64, y_mm: f64, dt_s: f64, w: &[f64; NC]) {
        let g = &self.grid;
        let (u, v) = g.frac_index(x_mm, y_mm);
        if !(u > -2.0 && v > -2.0 && u < g.rows as f64 + 1.0 && v < g.cols as f64 + 1.0) {
            return;
        }
        let (i0, j0) = (u.floor() as isize, v.floor() as isize);
        let (wu, wv) = (keys_weights(u - i0 as f64), keys_weights(v - j0 as f64));
        let mut vals = [0.0; NC];
        for c in 0..NC {
            vals[c] = dt_s * w[c];
        }
        for (a, wi) in wu.iter().enumerate() {
            let i = i0 - 1 + a as isize;
            if i < 0 || i as usize >= g.rows {
                continue;
            }
            let row = i as usize * g.cols;
            for (b, wj) in wv.iter().enumerate() {
                let j = j0 - 1 + b as isize;
                if j >= 0 && (j as usize) < g.cols {
                    let cell = &mut self.data[row + j as usize];
                    let k = wi * wj;
                    for c in 0..NC {
                        cell[c] += k * vals[c];
                    }
                }
            }
        }
    }

    /// As [`Self::add`] with 2 x 2 bilinear weights: keeps mass and centroid (not the second
    /// moment); used for the small correction channels, where it is a quarter of the work.
    pub fn add_bilinear(&mut self, x_mm: f64, y_mm: f64, dt_s: f64, w: &[f64; NC]) {
        let g = &self.grid;
        let (u, v) = g.frac_index(x_mm, y_mm);
        if !(u > -1.0 && v > -1.0 && u < g.rows as f64 && v < g.cols as f64) {
            return;
        }
        let (i0, j0) = (u.floor() as isize, v.floor() as isize);
        let (fu, fv) = (u - i0 as f64, v - j0 as f64);
        for (di, wi) in [(0isize, 1.0 - fu), (1, fu)] {
            let i = i0 + di;
            if i < 0 || i as usize >= g.rows {
                continue;
            }
            for (dj, wj) in [(0isize, 1.0 - fv), (1, fv)] {
                let j = j0 + dj;
                if j >= 0 && (j as usize) < g.cols {
                    let k = wi * wj * dt_s;
                    let cell = &mut self.data[i as usize * g.cols + j as usize];
                    for c in 0..NC {
                        cell[c] += k * w[c];
                    }
                }
            }
        }
    }

    /// One channel as a row-major vector.
    pub fn channel(&self, c: usize) -> Vec<f64> {
        self.data.iter().map(|v| v[c]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_mass_centroid_and_second_moment() {
        let g = Grid::new(20, 20, 0.5, 0.25, 1.0, -2.0).unwrap();
        let mut d = DwellChannels::<2>::new(g);
        d.add(4.37, 0.113, 2.0, &[1.0, -3.0]);
        let (mut m0, mut mx, mut my, mut vx, mut vy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..g.rows {
            for j in 0..g.cols {
                let w = d.data[i * g.cols + j][0];
                let (x, y) = (g.x_mm(j), g.y_mm(i));
                m0 += w;
                mx += w * x;
                my += w * y;
                vx += w * (x - 4.37).powi(2);
                vy += w * (y - 0.113).powi(2);
            }
        }
        assert!((m0 - 2.0).abs() < 1e-12);
        assert!((mx / m0 - 4.37).abs() < 1e-12 && (my / m0 - 0.113).abs() < 1e-12);
        assert!(vx.abs() < 1e-12 && vy.abs() < 1e-12);
        assert!((d.channel(1).iter().sum::<f64>() + 6.0).abs() < 1e-12);
        let mut b = DwellChannels::<1>::new(g);
        b.add_bilinear(4.37, 0.113, 2.0, &[1.0]);
        let (mut m0, mut mx) = (0.0, 0.0);
        for i in 0..g.rows {
            for j in 0..g.cols {
                m0 += b.data[i * g.cols + j][0];
                mx += b.data[i * g.cols + j][0] * g.x_mm(j);
            }
        }
        assert!((m0 - 2.0).abs() < 1e-12 && (mx / m0 - 4.37).abs() < 1e-12);
    }
}
