//! Fits used to judge energy behaviour: straight-line drift of an energy
//! error and the growth exponent of a power law.

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_fit_recovers_a_line() {
        let x: Vec<f64> = (0..50).map(|i| i as f64).collect();
        let y: Vec<f64> = x.iter().map(|x| 2.0 - 0.5 * x).collect();
        let f = fit_line(&x, &y).unwrap();
        assert!((f.slope + 0.5).abs() < 1e-12 && (f.intercept - 2.0).abs() < 1e-12);
        assert!(f.slope_std_error < 1e-12);
        assert!(fit_line(&[1.0, 1.0], &[0.0, 1.0]).is_none());
    }

    #[test]
    fn oscillation_has_no_drift_but_a_ramp_does() {
        let t: Vec<f64> = (0..2000).map(|i| i as f64 * 0.1).collect();
        let osc: Vec<f64> = t.iter().map(|t| 1e-6 * (3.0 * t).sin()).collect();
        assert!(energy_drift(&t, &osc).unwrap().drift_fraction < 0.05);
        let ramp: Vec<f64> = t.iter().map(|t| 1e-8 * t + 1e-7 * (3.0 * t).sin()).collect();
        let d = energy_drift(&t, &ramp).unwrap();
        assert!((d.slope - 1e-8).abs() < 1e-9 && d.drift_fraction > 0.5);
    }

    #[test]
    fn power_fit_recovers_exponent() {
        let t: Vec<f64> = (1..=10000).map(|i| i as f64 * 5.0).collect();
        let y: Vec<f64> = t.iter().map(|t| 3.0 * t.powf(1.5)).collect();
        let f = fit_power(&t, &y, 10.0, 100).unwrap();
        assert!((f.exponent - 1.5).abs() < 1e-10 && (f.coefficient - 3.0).abs() < 1e-8);
        assert!(f.points > 50 && f.points <= 100);
    }
}
