//! Number formats of tables, reports and figures, one of each: scientific
//! ([`sci`]), every digit ([`exact`]), durations ([`duration`]), short
//! decimals ([`short`]), and the
//! point lists of log-scale figures ([`log_points`], [`thin`]).

/// `x` in scientific notation with three decimals (`1.234e-5`).
pub fn sci(x: f64) -> String {
    sci_digits(x, 3)
}

/// `x` in scientific notation with `digits` decimals.
pub fn sci_digits(x: f64, digits: usize) -> String {
    format!("{x:.digits$e}")
}

/// `x` with every digit that tells it apart, as the runtime's error
/// messages print it ([`spark_runtime::Exact`]): for numbers a reader
/// compares, such as the two ends of an interval far from t = 0, which
/// [`sci`] prints alike.
pub fn exact(x: f64) -> String {
    spark_runtime::Exact(x).to_string()
}

/// A number without accumulated rounding noise (`12.600000000000001` → `12.6`).
pub fn short(x: f64) -> String {
    let s = format!("{x:.9}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// A duration in seconds, in engineering units (`12 ns`, `3.4 µs`,
/// `5.67 ms`, `1.23 s`; `–` when not finite).
pub fn duration(seconds: f64) -> String {
    if !seconds.is_finite() {
        "–".into()
    } else if seconds < 1e-6 {
        format!("{:.0} ns", seconds * 1e9)
    } else if seconds < 1e-3 {
        format!("{:.1} µs", seconds * 1e6)
    } else if seconds < 1.0 {
        format!("{:.2} ms", seconds * 1e3)
    } else {
        format!("{seconds:.2} s")
    }
}

/// A duration in seconds as whole nanoseconds (`123`).
pub fn nanoseconds(seconds: f64) -> String {
    format!("{:.0}", seconds * 1e9)
}

/// `(x, max(|y|, floor))` points for log axes.
pub fn log_points(x: &[f64], y: &[f64], floor: f64) -> Vec<(f64, f64)> {
    x.iter().zip(y).filter(|(_, y)| y.is_finite()).map(|(&x, &y)| (x, y.abs().max(floor))).collect()
}

/// Keeps at most `max` roughly evenly spaced points (figures need no more).
pub fn thin(points: Vec<(f64, f64)>, max: usize) -> Vec<(f64, f64)> {
    if points.len() <= max || max < 2 {
        return points;
    }
    let stride = points.len().div_ceil(max);
    let last = *points.last().expect("non-empty");
    let mut out: Vec<(f64, f64)> = points.into_iter().step_by(stride).collect();
    if out.last() != Some(&last) {
        out.push(last);
    }
    out
}
