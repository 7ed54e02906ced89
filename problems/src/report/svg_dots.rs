//! A scatter plot's SVG with its dots as paths: plotters writes every dot
//! as a `<circle>` element of about 95 bytes, so a Poincaré section that
//! covers most pixels of its panel writes tens of megabytes. A disc of
//! radius `r` is also the round cap of a zero-length stroke of width `2r`
//! (SVG 1.1, "a zero length subpath with `stroke-linecap` set to `round`
//! is stroked"), so a run of such discs of one colour is one `<path>` with a
//! subpath `M x y h0` (about 10 bytes) for each disc, drawn in the same
//! order.

use std::fmt::Write;

/// A dot as plotters' SVG backend writes a filled circle on one line:
/// its centre (whole pixels), radius and colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Dot<'a> {
    cx: i64,
    cy: i64,
    r: u32,
    fill: &'a str,
}

/// The dot that `line` draws: a filled, opaque, unstroked `<circle>` with
/// whole-pixel centre and radius, its attributes in the backend's order.
/// Any other line (a translucent or outlined circle, any other element) is
/// `None` and is kept as it is.
fn dot(line: &str) -> Option<Dot<'_>> {
    let rest = line.strip_prefix("<circle cx=\"")?;
    let (cx, rest) = rest.split_once("\" cy=\"")?;
    let (cy, rest) = rest.split_once("\" r=\"")?;
    let (r, rest) = rest.split_once("\" opacity=\"1\" fill=\"")?;
    let (fill, rest) = rest.split_once("\" stroke=\"none\" stroke-width=\"")?;
    let (_, end) = rest.split_once('"')?;
    let colour = fill.len() == 7 && fill.starts_with('#') && fill[1..].bytes().all(|b| b.is_ascii_hexdigit());
    if end != "/>" || !colour {
        return None;
    }
    Some(Dot { cx: cx.parse().ok()?, cy: cy.parse().ok()?, r: r.parse().ok()?, fill })
}

/// `svg` with every run of consecutive dots of one radius and colour
/// written as one path of zero-length round-capped subpaths, one a dot in
/// the run's order; every other line as it is. The discs are those the
/// circles draw, and the colours and their order are kept, so the picture
/// is the same.
pub fn compact_dots(svg: &str) -> String {
    let mut out = String::with_capacity(svg.len() / 4);
    let mut run: Option<(u32, &str)> = None;
    let close = |out: &mut String, run: &mut Option<(u32, &str)>| {
        if let Some((r, fill)) = run.take() {
            let width = 2 * u64::from(r);
            let _ =
                writeln!(out, "\" fill=\"none\" stroke=\"{fill}\" stroke-width=\"{width}\" stroke-linecap=\"round\"/>");
        }
    };
    for line in svg.split_inclusive('\n') {
        match dot(line.trim_end_matches('\n')) {
            Some(d) if d.r > 0 => {
                if run != Some((d.r, d.fill)) {
                    close(&mut out, &mut run);
                    out.push_str("<path d=\"");
                    run = Some((d.r, d.fill));
                }
                let _ = write!(out, "M{} {}h0", d.cx, d.cy);
            }
            _ => {
                close(&mut out, &mut run);
                out.push_str(line);
            }
        }
    }
    close(&mut out, &mut run);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle(cx: i64, cy: i64, r: u32, opacity: &str, fill: &str) -> String {
        format!("<circle cx=\"{cx}\" cy=\"{cy}\" r=\"{r}\" opacity=\"{opacity}\" fill=\"{fill}\" stroke=\"none\" stroke-width=\"1\"/>\n")
    }

    #[test]
    fn runs_of_one_colour_become_one_path_in_their_order() {
        let svg = [
            "<svg width=\"40\" height=\"30\">\n".to_string(),
            circle(1, 2, 1, "1", "#0072B2"),
            circle(-3, 40, 1, "1", "#0072B2"),
            circle(5, 6, 1, "1", "#D55E00"),
            "<text x=\"1\">a</text>\n".to_string(),
            circle(7, 8, 1, "1", "#D55E00"),
            circle(9, 9, 3, "1", "#D55E00"),
            circle(9, 9, 1, "0.5", "#D55E00"),
            "</svg>\n".to_string(),
        ]
        .concat();
        let want = [
            "<svg width=\"40\" height=\"30\">\n",
            "<path d=\"M1 2h0M-3 40h0\" fill=\"none\" stroke=\"#0072B2\" stroke-width=\"2\" stroke-linecap=\"round\"/>\n",
            "<path d=\"M5 6h0\" fill=\"none\" stroke=\"#D55E00\" stroke-width=\"2\" stroke-linecap=\"round\"/>\n",
            "<text x=\"1\">a</text>\n",
            "<path d=\"M7 8h0\" fill=\"none\" stroke=\"#D55E00\" stroke-width=\"2\" stroke-linecap=\"round\"/>\n",
            "<path d=\"M9 9h0\" fill=\"none\" stroke=\"#D55E00\" stroke-width=\"6\" stroke-linecap=\"round\"/>\n",
            // A translucent dot stays a circle: where translucent discs of
            // one path overlap, the stroke paints them once.
            "<circle cx=\"9\" cy=\"9\" r=\"1\" opacity=\"0.5\" fill=\"#D55E00\" stroke=\"none\" stroke-width=\"1\"/>\n",
            "</svg>\n",
        ]
        .concat();
        assert_eq!(compact_dots(&svg), want);
    }

    #[test]
    fn lines_that_are_not_plain_dots_are_kept() {
        for line in [
            "<circle cx=\"1\" cy=\"2\" r=\"0\" opacity=\"1\" fill=\"#000000\" stroke=\"none\" stroke-width=\"1\"/>",
            "<circle cx=\"1\" cy=\"2\" r=\"1\" opacity=\"1\" fill=\"none\" stroke=\"#000000\" stroke-width=\"1\"/>",
            "<circle cx=\"1.5\" cy=\"2\" r=\"1\" opacity=\"1\" fill=\"#000000\" stroke=\"none\" stroke-width=\"1\"/>",
            "<circle cx=\"1\" cy=\"2\" r=\"1\" opacity=\"1\" fill=\"#000000\" stroke=\"none\" stroke-width=\"1\">",
            "<circle cx=\"1\" cy=\"2\" r=\"1\" opacity=\"1\" fill=\"#00000\" stroke=\"none\" stroke-width=\"1\"/>",
            "<circle cx=\"1\" cy=\"2\" r=\"1\" opacity=\"1\" fill=\"#000000\" stroke=\"none\" stroke-width=\"1\"/> x",
            "<rect x=\"1\" y=\"2\"/>",
            "",
        ] {
            let svg = format!("{line}\n");
            assert_eq!(compact_dots(&svg), svg);
            // Without its newline too (the last line of a file).
            assert_eq!(compact_dots(line), line);
        }
    }
}
