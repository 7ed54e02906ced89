//! `spark section`: integrate an ensemble and record where it crosses one
//! of the system's declared events.

use super::{parse_method, parse_params, step_count, step_flag, Newton};
use crate::catalog::lookup;
use crate::experiments::section::{
    default_axes, find_event, parse_axis, run_section, write_section, SectionSpec, MAX_SECTION_MEMBERS,
};
use crate::report::files::OutputDir;
use crate::report::format::exact;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
/// Arguments of `spark section`.
pub struct SectionArgs {
    /// System, by name or type name, any case (see `spark list`); it must
    /// declare events.
    #[arg(value_name = "SYSTEM")]
    pub system: String,
    /// Name of the declared event whose crossings make the section.
    #[arg(long)]
    pub event: String,
    /// Ensemble size J (members 0..J; for the McLachlan–Perlmutter particles
    /// the paper's initial states j = 0..J−1).
    #[arg(long, default_value_t = 10)]
    pub members: usize,
    /// Method (as for `spark run`).
    #[arg(long, short, default_value = "gauss")]
    pub method: String,
    /// Number of stages s.
    #[arg(long, short, default_value_t = 2)]
    pub stages: usize,
    /// Step size h (default: the system's, see `spark list`).
    #[arg(long = "h", visible_alias = "step", allow_hyphen_values = true)]
    pub h: Option<f64>,
    /// Final time of every member (default: the system's); t_end − t0 must
    /// be a whole number of steps of h.
    #[arg(long, short, allow_hyphen_values = true)]
    pub t_end: Option<f64>,
    /// Set a system parameter, e.g. --param alpha=0.3 (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Horizontal axis of the figure: q_NAME, v_NAME or a coordinate name
    /// (default: chosen per system).
    #[arg(long)]
    pub x: Option<String>,
    /// Vertical axis of the figure (as --x).
    #[arg(long)]
    pub y: Option<String>,
    /// Newton iteration.
    #[arg(long, value_enum, default_value_t = Newton::Full)]
    pub newton: Newton,
    /// A member's step whose Newton iteration fails is replaced by two half
    /// steps, nested at most this many levels deep, 0 to 60; the output
    /// counts them. 0 ends the section at the first step that fails.
    #[arg(long, default_value_t = spark_runtime::DEFAULT_MAX_HALVINGS,
          value_parser = clap::value_parser!(u32).range(0..=spark_runtime::MAX_HALVINGS as i64))]
    pub max_halvings: u32,
    /// Output folder (created and locked; files appear when the run ends).
    #[arg(long, short, default_value = "results/section")]
    pub out: PathBuf,
}

/// `spark section`: a Poincaré section of an ensemble.
pub fn section_command(a: SectionArgs) -> Result<String, String> {
    let entry = lookup(&a.system).map_err(|e| e.to_string())?;
    // The event and the axes are checked before anything runs.
    find_event(entry.kind, &a.event).map_err(|e| e.to_string())?;
    let (dx, dy) = default_axes(entry.kind);
    let x = a.x.as_deref().map(|n| parse_axis(entry, "--x", n)).transpose().map_err(|e| e.to_string())?.unwrap_or(dx);
    let y = a.y.as_deref().map(|n| parse_axis(entry, "--y", n)).transpose().map_err(|e| e.to_string())?.unwrap_or(dy);
    let method = parse_method(&a.method)?;
    let h = a.h.unwrap_or(entry.h);
    let t0 = entry.t0;
    if !(h.is_finite() && h > 0.0) {
        return Err(format!("--h must be a positive number, got {h:.3e}"));
    }
    spark_runtime::check_step_size(t0, h).map_err(|why| format!("{} from t0 = {t0:.3e}: {why}", step_flag(a.h, h)))?;
    let t_end = a.t_end.unwrap_or(t0 + entry.t_end);
    if !(t_end.is_finite() && t_end > t0) {
        return Err(format!("--t-end must be a number greater than t0 = {}, got {}", exact(t0), exact(t_end)));
    }
    if a.stages == 0 {
        return Err("--stages must be at least 1".into());
    }
    if a.members == 0 || a.members > MAX_SECTION_MEMBERS {
        return Err(format!("--members must lie in 1..={}, got {}", MAX_SECTION_MEMBERS, a.members));
    }
    let steps = step_count(t0, t_end, h)?;
    // Every member takes every step: the work is their product.
    if steps as f64 * a.members as f64 > super::MAX_STEPS {
        return Err(format!(
            "--members {} × {steps} steps (t = {} … {} with h = {h:.3e}) is {:.3e} steps in all, \
             more than {:.0e}, the most one section takes (hours at 0.1–1 µs per step); use fewer --members, a \
             shorter --t-end or a larger --h",
            a.members,
            exact(t0),
            exact(t_end),
            steps as f64 * a.members as f64,
            super::MAX_STEPS
        ));
    }
    let newton = spark_runtime::NewtonOptions { mode: a.newton.into(), ..spark_runtime::NewtonOptions::default() };
    let spec = SectionSpec {
        system: entry.kind,
        event: a.event.clone(),
        members: a.members,
        method,
        stages: a.stages,
        h,
        steps,
        t0,
        parameters: parse_params(&a.params)?,
        newton,
        max_halvings: a.max_halvings,
    };
    let mut out = OutputDir::open(&a.out).map_err(|e| e.to_string())?;
    let section = run_section(&spec).map_err(|e| e.to_string())?;
    if section.points.is_empty() {
        return Err(format!(
            "no member crossed `{}` ({} = 0, {:?}) by t = {}: there is no crossing of the event to plot; \
             integrate longer with --t-end, or choose another event",
            section.event,
            section.source,
            section.direction,
            exact(t_end)
        ));
    }
    write_section(&section, &spec, (x, y), &mut out).map_err(|e| e.to_string())?;
    let files = out.commit().map_err(|e| e.to_string())?;
    let mut text = format!(
        "{} {} ({}): {} crossings of {} = 0 in {} member(s) to t = {}, max |g| = {:.3e}\n",
        entry.name,
        section.event,
        method.name(),
        section.points.len(),
        section.source,
        a.members,
        exact(t_end),
        section.max_residual()
    );
    let halved = section.rejected_steps.iter().filter(|&&r| r > 0).count();
    if halved > 0 {
        text.push_str(&format!(
            "steps halved: {halved} of {} member(s) halved steps whose Newton iteration failed at h = {} ({} \
             halvings in all; section.json's rejected_steps_per_member): their crossings are not those of fixed \
             steps h alone; use a smaller --h, or --max-halvings 0 to make such a step an error\n",
            a.members,
            exact(h),
            section.rejected_steps.iter().sum::<usize>()
        ));
    }
    for f in files {
        text.push_str(&format!("wrote {}\n", f.display()));
    }
    Ok(text)
}
