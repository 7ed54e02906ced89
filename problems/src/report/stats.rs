//! Statistics the experiments judge runs by: straight-line and power-law
//! fits, the drift test of an energy error, medians, the structure function
//! of an ensemble's energy errors and the §8.4 ensemble statistic.

/// A least-squares straight line `y ≈ intercept + slope·x`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LineFit {
    /// Slope.
    pub slope: f64,
    /// Intercept.
    pub intercept: f64,
    /// Standard error of the slope (0 with fewer than 3 points).
    pub slope_std_error: f64,
    /// Points used.
    pub points: usize,
}

/// Least-squares line through the finite points `(x, y)`; `None` with fewer
/// than two distinct `x`.
pub fn fit_line(x: &[f64], y: &[f64]) -> Option<LineFit> {
    let pts: Vec<(f64, f64)> =
        x.iter().zip(y).map(|(&a, &b)| (a, b)).filter(|(a, b)| a.is_finite() && b.is_finite()).collect();
    let n = pts.len();
    if n < 2 {
        return None;
    }
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n as f64;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n as f64;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let slope_std_error = if n > 2 {
        let ssr: f64 = pts.iter().map(|p| (p.1 - intercept - slope * p.0).powi(2)).sum();
        (ssr / (n - 2) as f64 / sxx).sqrt()
    } else {
        0.0
    };
    Some(LineFit { slope, intercept, slope_std_error, points: n })
}

/// Linear drift of an energy error `e(t)`: the fitted slope and how much of
/// the observed error band a straight line would explain over the interval.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Drift {
    /// Fitted slope of `E − E0` against `t` (energy per unit time).
    pub slope: f64,
    /// Standard error of the slope.
    pub slope_std_error: f64,
    /// `|slope|·(t_end − t_0) / max|E − E0|`: well below 1 means the error is
    /// a bounded oscillation, near 1 or above a linear drift.
    pub drift_fraction: f64,
}

/// Fits `E − E0 = a + b t` and compares the drift over the interval with the
/// largest error seen.
pub fn energy_drift(t: &[f64], error: &[f64]) -> Option<Drift> {
    let fit = fit_line(t, error)?;
    let span = t.last()? - t.first()?;
    let max = error.iter().filter(|e| e.is_finite()).fold(0.0f64, |m, e| m.max(e.abs()));
    let drift_fraction = if max > 0.0 { (fit.slope * span).abs() / max } else { 0.0 };
    Some(Drift { slope: fit.slope, slope_std_error: fit.slope_std_error, drift_fraction })
}

/// A power law `y ≈ C·t^p`, fitted on log–log axes.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PowerFit {
    /// Exponent `p`.
    pub exponent: f64,
    /// Standard error of the exponent.
    pub exponent_std_error: f64,
    /// `C`.
    pub coefficient: f64,
    /// First `t` of the fitting window.
    pub t_min: f64,
    /// Points used.
    pub points: usize,
}

/// Fits `y = C t^p` to the points with `t ≥ t_min`, `t > 0`, `y > 0`, using
/// up to `bins` points spread evenly in `log t` (so the many late samples of
/// an evenly sampled run do not outweigh the early decades).
pub fn fit_power(t: &[f64], y: &[f64], t_min: f64, bins: usize) -> Option<PowerFit> {
    let pts: Vec<(f64, f64)> = t
        .iter()
        .zip(y)
        .map(|(&a, &b)| (a, b))
        .filter(|&(a, b)| a >= t_min && a > 0.0 && b > 0.0 && b.is_finite())
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let (l0, l1) = (pts[0].0.ln(), pts[pts.len() - 1].0.ln());
    let mut chosen: Vec<(f64, f64)> = Vec::new();
    let mut next_edge = l0;
    let step = if bins > 1 { (l1 - l0) / (bins - 1) as f64 } else { f64::INFINITY };
    for &(a, b) in &pts {
        if a.ln() >= next_edge - 1e-12 {
            chosen.push((a.ln(), b.ln()));
            next_edge = a.ln() + step;
        }
    }
    let (lx, ly): (Vec<f64>, Vec<f64>) = chosen.into_iter().unzip();
    let fit = fit_line(&lx, &ly)?;
    Some(PowerFit {
        exponent: fit.slope,
        exponent_std_error: fit.slope_std_error,
        coefficient: fit.intercept.exp(),
        t_min: pts[0].0,
        points: fit.points,
    })
}

/// The median (the mean of the middle two for an even count; NaN when empty).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Median of the positive finite values, the geometric mean of the middle
/// two for an even count (for ratios); `None` when there are none.
pub fn positive_median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite() && *x > 0.0);
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 { v[n / 2] } else { (v[n / 2 - 1] * v[n / 2]).sqrt() })
}

/// Slope of `|E − E₀|` against `t` judged two ways: ordinary least squares
/// over all samples (its standard error assumes independent samples, which
/// the oscillating error is not, so it is too small), and least squares
/// through `blocks` block means (an honest standard error for correlated
/// samples).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DriftTest {
    /// OLS slope of `|E − E₀|`.
    pub slope: f64,
    /// Its (optimistic) standard error.
    pub slope_std_error: f64,
    /// Slope through the block means.
    pub block_slope: f64,
    /// Its standard error.
    pub block_std_error: f64,
    /// `|slope|·(t_end − t₀) / max|E − E₀|` (the share of the error band a
    /// linear drift would explain; from [`energy_drift`]).
    pub drift_fraction: f64,
}

impl DriftTest {
    /// No drift: the block slope is within 3 standard errors of zero, or a
    /// linear drift explains under 5 % of the error band.
    pub fn no_drift(&self) -> bool {
        self.block_slope.abs() <= 3.0 * self.block_std_error || self.drift_fraction < 0.05
    }
}

/// Tests `|E − E₀|(t)` for a linear drift (see [`DriftTest`]).
pub fn drift_test(t: &[f64], error: &[f64], blocks: usize) -> Option<DriftTest> {
    let abs: Vec<f64> = error.iter().map(|e| e.abs()).collect();
    let ols = fit_line(t, &abs)?;
    let d = energy_drift(t, &abs)?;
    let per = (t.len() / blocks.max(2)).max(1);
    let (bt, be): (Vec<f64>, Vec<f64>) = t
        .chunks(per)
        .zip(abs.chunks(per))
        .map(|(a, b)| (a.iter().sum::<f64>() / a.len() as f64, b.iter().sum::<f64>() / b.len() as f64))
        .unzip();
    let blk = fit_line(&bt, &be)?;
    Some(DriftTest {
        slope: ols.slope,
        slope_std_error: ols.slope_std_error,
        block_slope: blk.slope,
        block_std_error: blk.slope_std_error,
        drift_fraction: d.drift_fraction,
    })
}

/// Structure function of ensemble energy errors sampled every `dt`:
/// `S(Δ) = (1/h⁴)·mean_{j,k} (e_j[k + l] − e_j[k])²` for the lags
/// `Δ = l·dt`, `l = 1, 2, 4, …` (up to half the series). Averaging over every
/// start time uses the whole run, so it is much less noisy than the ensemble
/// mean at one time: a random walk gives `S(Δ) ≈ 2σ² + DΔ`, a bounded
/// error a plateau `S(Δ) → 2σ²`. Returns `(Δ, S(Δ))` pairs.
pub fn energy_structure_function(members: &[&[f64]], dt: f64, h: f64) -> Vec<(f64, f64)> {
    let len = members.iter().map(|e| e.len()).min().unwrap_or(0);
    let h4 = h.powi(4);
    (0..)
        .map(|k| 1usize << k)
        .take_while(|&l| l < len / 2)
        .map(|l| {
            let (mut sum, mut n) = (0.0, 0usize);
            for e in members {
                for (late, early) in e[l..len].iter().zip(&e[..len - l]) {
                    sum += (late - early).powi(2);
                    n += 1;
                }
            }
            (l as f64 * dt, sum / n.max(1) as f64 / h4)
        })
        .collect()
}

/// The plateau of a structure function: its largest value over the lags
/// `Δ ≤ plateau_until` (the bounded `O(h²)` oscillation decorrelates within a
/// few time units, so these lags measure `2σ²`).
pub fn structure_plateau(sf: &[(f64, f64)], plateau_until: f64) -> f64 {
    sf.iter().filter(|(d, _)| *d <= plateau_until).map(|(_, s)| *s).fold(0.0, f64::max)
}

/// Log–log slope of `S(Δ) − plateau` over the `last` largest lags of a
/// structure function (see [`structure_plateau`]): ≈ 1 for a random walk;
/// `None` for a bounded error, when fewer than three of those lags rise above
/// the plateau.
pub fn structure_slope(sf: &[(f64, f64)], plateau_until: f64, last: usize) -> Option<LineFit> {
    let base = structure_plateau(sf, plateau_until);
    let (x, y): (Vec<f64>, Vec<f64>) = sf
        .iter()
        .skip(sf.len().saturating_sub(last))
        .filter(|(d, s)| *d > plateau_until && *s > base)
        .map(|(d, s)| (d.ln(), (s - base).ln()))
        .unzip();
    // Two points always give a line; a slope needs a third to mean anything.
    if x.len() < 3 {
        return None;
    }
    fit_line(&x, &y)
}

/// Mean of `y` over the samples with `lo ≤ t ≤ hi`.
pub fn window_mean(t: &[f64], y: &[f64], lo: f64, hi: f64) -> f64 {
    let v: Vec<f64> = t.iter().zip(y).filter(|(t, _)| **t >= lo && **t <= hi).map(|(_, y)| *y).collect();
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Means of `(x, y)` over `bins` bins evenly spaced in `log x` (points with
/// `x ≤ 0` are skipped; empty bins give no point).
pub fn log_bin_means(points: &[(f64, f64)], bins: usize) -> Vec<(f64, f64)> {
    let pts: Vec<(f64, f64)> = points.iter().copied().filter(|p| p.0 > 0.0).collect();
    let (Some(first), Some(last)) = (pts.first(), pts.last()) else { return Vec::new() };
    let (l0, l1) = (first.0.ln(), last.0.ln());
    let width = ((l1 - l0) / bins.max(1) as f64).max(f64::MIN_POSITIVE);
    let mut sums = vec![(0.0, 0.0, 0usize); bins.max(1)];
    for &(x, y) in &pts {
        let k = (((x.ln() - l0) / width) as usize).min(sums.len() - 1);
        sums[k].0 += x;
        sums[k].1 += y;
        sums[k].2 += 1;
    }
    sums.into_iter().filter(|s| s.2 > 0).map(|(x, y, n)| (x / n as f64, y / n as f64)).collect()
}

/// `(1/h⁴)·(1/(J+1)) Σ_j (E_jk − E_j0)²` at each common sample `k` of the
/// members' energies `E_j·` (each with its initial energy `E_j0`).
pub fn ensemble_quantity(members: &[(&[f64], f64)], h: f64) -> Vec<f64> {
    let samples = members.iter().map(|(e, _)| e.len()).min().unwrap_or(0);
    let h4 = h.powi(4);
    (0..samples)
        .map(|k| members.iter().map(|(e, e0)| (e[k] - e0).powi(2)).sum::<f64>() / members.len() as f64 / h4)
        .collect()
}
