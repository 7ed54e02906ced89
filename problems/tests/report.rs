//! The report wing: statistics, the thread clock, figures, number formats
//! and the atomically written table files.

mod stats {
    use problems::report::stats::*;

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

mod clock {
    use problems::report::clock::*;

    #[test]
    fn thread_clock_advances_with_work() {
        let start = thread_cpu_seconds();
        let mut x = 0.0f64;
        for i in 0..2_000_000 {
            x += (i as f64).sqrt();
        }
        std::hint::black_box(x);
        assert!(thread_cpu_seconds() > start);
    }
}

mod plot {
    use problems::report::plot::*;

    #[test]
    fn log_axis_ticks_are_never_rounded_to_zero() {
        // A log axis passes span 0: 1e-10 must print as itself, not "0".
        assert_eq!(tick_label(1e-10, 0.0), "1.0e-10");
        assert_eq!(tick_label(1e-16, 0.0), "1.0e-16");
        // A linear axis spanning 1 still shows round-off around 0 as "0".
        assert_eq!(tick_label(1e-12, 1.0), "0");
    }

    #[test]
    fn writes_png_and_svg_with_text() {
        let dir = std::env::temp_dir().join(format!("spark-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pts: Vec<(f64, f64)> = (0..200).map(|i| (i as f64 * 0.1, (i as f64 * 0.1).sin() * 1e-9)).collect();
        let fig = Figure {
            title: "Test figure".into(),
            panels: vec![
                Panel {
                    title: "linear".into(),
                    x_label: "t".into(),
                    y_label: "E − E0".into(),
                    x_scale: Scale::Linear,
                    y_scale: Scale::Linear,
                    series: vec![Series::new("sin", pts.clone())],
                },
                Panel {
                    title: "log".into(),
                    x_label: "t".into(),
                    y_label: "y".into(),
                    x_scale: Scale::Log,
                    y_scale: Scale::Log,
                    series: vec![Series { label: "ref".into(), points: vec![(1.0, 1.0), (10.0, 10.0)], dashed: true }],
                },
            ],
            columns: 2,
            panel_size: (400, 300),
        };
        let files = [dir.join("fig.png"), dir.join("fig.svg")];
        render_files(&fig, &files[0], &files[1]).unwrap();
        let png = std::fs::read(&files[0]).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        let svg = std::fs::read_to_string(&files[1]).unwrap();
        assert!(svg.contains("Test figure") && svg.contains("E − E0"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn empty_log_panel_is_an_error() {
        let fig = Figure {
            title: "F".into(),
            panels: vec![Panel {
                title: "P".into(),
                x_label: "x".into(),
                y_label: "y".into(),
                x_scale: Scale::Linear,
                y_scale: Scale::Log,
                series: vec![Series::new("zero", vec![(0.0, 0.0), (1.0, -1.0)])],
            }],
            columns: 1,
            panel_size: (200, 200),
        };
        let dir = std::env::temp_dir().join(format!("spark-plot-empty-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let err = render_files(&fig, &dir.join("f.png"), &dir.join("f.svg")).unwrap_err();
        assert!(err.to_string().contains("log scale"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Of the points on one pixel only the last one drawn is kept, and the
    /// kept ones keep the order of their last occurrence.
    #[test]
    fn a_scatter_keeps_the_last_dot_on_each_pixel() {
        let series = vec![vec![(0, 'a'), (1, 'b'), (0, 'c'), (2, 'd')], vec![(2, 'e'), (3, 'f'), (3, 'g')]];
        let kept = last_dot_per_pixel(&series, |p| p.0);
        assert_eq!(kept, vec![vec![(1, 'b'), (0, 'c')], vec![(2, 'e'), (3, 'g')]]);
    }

    /// A section whose crossings fall on the same pixels again and again
    /// (a periodic orbit) writes an SVG of at most one dot per point drawn
    /// once, and the same PNG and SVG as those points drawn once.
    #[test]
    fn a_scatter_draws_one_dot_per_pixel() {
        let dir = std::env::temp_dir().join(format!("spark-plot-dots-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let once: Vec<(f64, f64)> = (0..500).map(|i| (0.0126 * i as f64).sin_cos()).collect();
        let repeated: Vec<(f64, f64)> = once.iter().cycle().take(200 * once.len()).copied().collect();
        let figure = |points| Scatter {
            title: "section".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: vec![Series::new("member 0", points)],
            size: (400, 300),
        };
        let [png_once, svg_once, png_repeated, svg_repeated] =
            ["once.png", "once.svg", "repeated.png", "repeated.svg"].map(|f| dir.join(f));
        render_scatter_files(&figure(once), &png_once, &svg_once).unwrap();
        render_scatter_files(&figure(repeated), &png_repeated, &svg_repeated).unwrap();
        let svg = std::fs::read_to_string(&svg_repeated).unwrap();
        // 500 dots and the legend's one, each a subpath `M x y h0` of a
        // path of its colour, not a `<circle>` element.
        let dots = svg.matches("h0").count();
        assert!((400..=501).contains(&dots), "{dots} dots");
        assert_eq!(svg.matches("<circle").count(), 0);
        assert!(svg.matches("<path").count() <= 3, "{svg}");
        assert!(svg.len() < 15 * dots + 12_000, "{} bytes for {dots} dots", svg.len());
        assert_eq!(svg, std::fs::read_to_string(&svg_once).unwrap());
        assert!(std::fs::read(&png_repeated).unwrap() == std::fs::read(&png_once).unwrap(), "the same PNG");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Values near the end of f64's range (a run from `--q0 1.7e308,0,0`)
    /// are left out of the figures with a note in the legend: plotters
    /// loops forever on an axis spanning about 1e307 or more. The figures
    /// are drawn on a thread, so that a hang fails the test instead of
    /// stalling it.
    #[test]
    fn values_near_the_end_of_the_f64_range_do_not_hang_the_figures() {
        let dir = std::env::temp_dir().join(format!("spark-plot-huge-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (done, finished) = std::sync::mpsc::channel();
        let d = dir.clone();
        std::thread::spawn(move || {
            let huge = |y0: f64, y1: f64| vec![(0.0, y0), (0.1, y1)];
            let panel = |series| Panel {
                title: "q".into(),
                x_label: "t".into(),
                y_label: "q".into(),
                x_scale: Scale::Linear,
                y_scale: Scale::Linear,
                series,
            };
            let fig = Figure {
                title: "huge".into(),
                panels: vec![
                    panel(vec![Series::new("x", huge(0.0, 1.7e308)), Series::new("y", huge(0.0, 1.0))]),
                    panel(vec![Series::new("x", huge(-1e308, 1e308)), Series::new("y", huge(0.0, 1.0))]),
                ],
                columns: 2,
                panel_size: (300, 200),
            };
            let drawn = render_files(&fig, &d.join("f.png"), &d.join("f.svg"));
            let scatter = Scatter {
                title: "section".into(),
                x_label: "x".into(),
                y_label: "y".into(),
                series: vec![Series::new("member 0", vec![(-1.7e308, 0.0), (1.7e308, 1.0), (0.0, 0.5)])],
                size: (300, 200),
            };
            let scattered = render_scatter_files(&scatter, &d.join("s.png"), &d.join("s.svg"));
            let only_huge =
                Figure { panels: vec![panel(vec![Series::new("x", huge(1.7e308, -1.7e308))])], ..fig.clone() };
            let empty = render_files(&only_huge, &d.join("e.png"), &d.join("e.svg"));
            let _ = done.send((drawn, scattered, empty));
        });
        let (drawn, scattered, empty) =
            finished.recv_timeout(std::time::Duration::from_secs(60)).expect("drawing finishes");
        drawn.unwrap();
        scattered.unwrap();
        let svg = std::fs::read_to_string(dir.join("f.svg")).unwrap();
        assert!(svg.contains("values beyond ±1e300 not drawn"), "the legend says what is left out");
        let err = empty.unwrap_err().to_string();
        assert!(err.contains("values beyond ±1e300 are not drawn"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

mod format {
    use problems::report::format::*;

    #[test]
    fn formats() {
        assert_eq!(sci(12344.0), "1.234e4");
        assert_eq!(sci_digits(12344.0, 2), "1.23e4");
        assert_eq!(short(12.600000000000001), "12.6");
        assert_eq!(duration(2.5e-6), "2.5 µs");
        assert_eq!(nanoseconds(1.5e-7), "150");
        assert_eq!(thin((0..10).map(|i| (i as f64, 0.0)).collect(), 4).last(), Some(&(9.0, 0.0)));
    }
}

mod files {
    use problems::report::files::*;

    #[test]
    fn columns_round_trip_exactly() {
        let dir = std::env::temp_dir().join(format!("spark-out-{}", std::process::id()));
        create_dir(&dir).unwrap();
        let p = dir.join("c.csv");
        let a = [0.1, 1.0 / 3.0, -2.5e-17];
        let b = [1.0, f64::MIN_POSITIVE, 7.0];
        write_columns(&p, &[("a", &a), ("b", &b)]).unwrap();
        let (h, cols) = read_columns(&p).unwrap();
        assert_eq!(h, vec!["a", "b"]);
        assert_eq!(cols[0], a.to_vec());
        assert_eq!(cols[1], b.to_vec());
        let bad = write_columns(&p, &[("a", &a), ("b", &b[..2])]);
        assert!(matches!(bad, Err(OutputError::Ragged { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
