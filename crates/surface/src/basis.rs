//! Polynomial bases for form removal: Fringe Zernike polynomials on the unit disc and
//! Legendre products on the square [-1, 1]^2.
//!
//! Zernike conventions: Fringe (University of Arizona) ordering, 1-based index j = 1..=37,
//! unnormalised (Z_1 = 1; every term has the value 1 at r = 1 along its cosine axis).
//! Z_j(x, y) = R_n^|m|(r) cos(|m| theta) for m >= 0 and R_n^|m|(r) sin(|m| theta) for m < 0,
//! with theta measured from +x towards +y. On the unit disc the mean of Z_j^2 is 1 / (n + 1)
//! when m = 0 and 1 / (2 (n + 1)) otherwise, and distinct terms are orthogonal.
//!
//! Legendre conventions: P_a(u) P_b(v) with total degree a + b <= D, ordered by degree, then
//! by decreasing a (so degree 1 is u, then v). Orthogonal on the square [-1, 1]^2.

use std::sync::OnceLock;

/// Largest Fringe Zernike index supported.
pub const MAX_ZERNIKE: usize = 37;
/// Largest total Legendre degree supported.
pub const MAX_LEGENDRE_DEGREE: usize = 12;

/// (n, m) of the Fringe Zernike terms 1..=37; m < 0 selects the sine term.
pub const FRINGE_NM: [(u32, i32); MAX_ZERNIKE] = [
    (0, 0),
    (1, 1),
    (1, -1),
    (2, 0),
    (2, 2),
    (2, -2),
    (3, 1),
    (3, -1),
    (4, 0),
    (3, 3),
    (3, -3),
    (4, 2),
    (4, -2),
    (5, 1),
    (5, -1),
    (6, 0),
    (4, 4),
    (4, -4),
    (5, 3),
    (5, -3),
    (6, 2),
    (6, -2),
    (7, 1),
    (7, -1),
    (8, 0),
    (5, 5),
    (5, -5),
    (6, 4),
    (6, -4),
    (7, 3),
    (7, -3),
    (8, 2),
    (8, -2),
    (9, 1),
    (9, -1),
    (10, 0),
    (12, 0),
];

/// R_n^m(r) = r^m Q(r^2); the coefficients of Q in ascending powers of r^2.
fn radial_q(n: u32, m: u32) -> Vec<f64> {
    let fact = |k: u32| (1..=k).fold(1.0f64, |a, b| a * b as f64);
    let half = (n - m) / 2;
    let mut q = vec![0.0; half as usize + 1];
    for k in 0..=half {
        let c = fact(n - k) / (fact(k) * fact((n + m) / 2 - k) * fact(half - k));
        let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
        // r^(n-2k) = r^m (r^2)^(half - k)
        q[(half - k) as usize] = sign * c;
    }
    q
}

fn radial_table() -> &'static Vec<Vec<f64>> {
    static TABLE: OnceLock<Vec<Vec<f64>>> = OnceLock::new();
    TABLE.get_or_init(|| {
        FRINGE_NM
            .iter()
            .map(|&(n, m)| radial_q(n, m.unsigned_abs()))
            .collect()
    })
}

/// Appends Fringe Zernike terms 1..=count at (x, y) (unit-disc coordinates) to `out`.
/// Uses Re/Im of (x + i y)^|m| = r^|m| cos / sin(|m| theta), so no angle is computed.
pub fn push_zernike(count: usize, x: f64, y: f64, out: &mut Vec<f64>) {
    let count = count.min(MAX_ZERNIKE);
    let table = radial_table();
    let s = x * x + y * y;
    // Powers (x + i y)^k for k = 0..=5 (the largest |m| among the 37 terms).
    let mut pw = [(1.0f64, 0.0f64); 6];
    for k in 1..6 {
        let (a, b) = pw[k - 1];
        pw[k] = (a * x - b * y, a * y + b * x);
    }
    for (j, &(_, m)) in FRINGE_NM.iter().enumerate().take(count) {
        let q = &table[j];
        let mut poly = 0.0;
        for &c in q.iter().rev() {
            poly = poly * s + c;
        }
        let (re, im) = pw[m.unsigned_abs() as usize];
        out.push(poly * if m >= 0 { re } else { im });
    }
}

/// Fringe Zernike term `j` (1-based) at (x, y); 0 for an index outside 1..=37.
pub fn fringe_zernike(j: usize, x: f64, y: f64) -> f64 {
    if j == 0 || j > MAX_ZERNIKE {
        return 0.0;
    }
    let mut v = Vec::with_capacity(j);
    push_zernike(j, x, y, &mut v);
    v[j - 1]
}

/// Number of Legendre products of total degree <= `degree`.
pub fn legendre_count(degree: usize) -> usize {
    (degree + 1) * (degree + 2) / 2
}

/// Legendre polynomials P_0..=P_degree at t (three-term recurrence).
fn legendre_values(degree: usize, t: f64, out: &mut [f64; MAX_LEGENDRE_DEGREE + 1]) {
    out[0] = 1.0;
    if degree >= 1 {
        out[1] = t;
    }
    for k in 1..degree {
        let kf = k as f64;
        out[k + 1] = ((2.0 * kf + 1.0) * t * out[k] - kf * out[k - 1]) / (kf + 1.0);
    }
}

/// Appends the Legendre products of total degree <= `degree` at (u, v) to `out`.
pub fn push_legendre(degree: usize, u: f64, v: f64, out: &mut Vec<f64>) {
    let degree = degree.min(MAX_LEGENDRE_DEGREE);
    let mut pu = [0.0; MAX_LEGENDRE_DEGREE + 1];
    let mut pv = [0.0; MAX_LEGENDRE_DEGREE + 1];
    legendre_values(degree, u, &mut pu);
    legendre_values(degree, v, &mut pv);
    for d in 0..=degree {
        for a in (0..=d).rev() {
            out.push(pu[a] * pv[d - a]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_order_zernike_match_their_closed_forms() {
        let (x, y) = (0.3, -0.55);
        let r2 = x * x + y * y;
        let closed = [
            1.0,
            x,
            y,
            2.0 * r2 - 1.0,
            x * x - y * y,
            2.0 * x * y,
            (3.0 * r2 - 2.0) * x,
            (3.0 * r2 - 2.0) * y,
            6.0 * r2 * r2 - 6.0 * r2 + 1.0,
        ];
        for (j, c) in closed.iter().enumerate() {
            let z = fringe_zernike(j + 1, x, y);
            assert!((z - c).abs() < 1e-14, "Z{} = {z}, closed form {c}", j + 1);
        }
        // Z37 = R_12^0: 924 r^12 - 2772 r^10 + 3150 r^8 - 1680 r^6 + 420 r^4 - 42 r^2 + 1.
        let z37 = [1.0, -42.0, 420.0, -1680.0, 3150.0, -2772.0, 924.0]
            .iter()
            .rev()
            .fold(0.0, |a, c| a * r2 + c);
        assert!((fringe_zernike(37, x, y) - z37).abs() < 1e-12);
        // Every cosine term is 1 at (1, 0).
        for (j, &(_, m)) in FRINGE_NM.iter().enumerate() {
            if m >= 0 {
                assert!(
                    (fringe_zernike(j + 1, 1.0, 0.0) - 1.0).abs() < 1e-10,
                    "Z{}",
                    j + 1
                );
            }
        }
    }

    #[test]
    fn legendre_products_match_closed_forms() {
        let (u, v) = (0.4, -0.7);
        let mut out = Vec::new();
        push_legendre(2, u, v, &mut out);
        let p2 = |t: f64| 1.5 * t * t - 0.5;
        let want = [1.0, u, v, p2(u), u * v, p2(v)];
        assert_eq!(out.len(), legendre_count(2));
        for (a, b) in out.iter().zip(want) {
            assert!((a - b).abs() < 1e-15);
        }
        let mut out = Vec::new();
        push_legendre(4, 1.0, 1.0, &mut out);
        assert!(out.iter().all(|&p| (p - 1.0).abs() < 1e-14), "P_k(1) = 1");
    }
}
