//! The sine and cosine for the code `nonholonomic_system!` generates: of
//! one angle together ([`sin_cos`]), and alone ([`sin`], [`cos`], the same
//! bits as the pair's members).
//!
//! A body that needs both `sin θ` and `cos θ` (the skate's and the mobile
//! robot's constraints, every rotation) gets them from one call of
//! [`sin_cos`]: the argument is reduced by `π/2` once and both of fdlibm's
//! kernel polynomials run on the reduced value. The platform's libm pays
//! ≈ 136 instructions for the pair (glibc's `sincos`, into which LLVM fuses
//! the two calls); this pays ≈ 100, 4 % of the skate's Gauss s = 1 step
//! (docs/performance/README.md, "The sine–cosine pair"). It is out of
//! line: inlined, it grows the generated stage functions past LLVM's
//! inlining threshold, and their calls cost more than the pair saves.
//!
//! The reduction is fdlibm's `__rem_pio2` medium case, as musl and the
//! `libm` crate have it: `x = n·π/2 + y`, with `π/2` in parts of 33 bits and
//! a second and a third round where the first cancels, exact for
//! `|x| < 2²⁰·π/2`. The reduced head and tail go into `__kernel_sin` and
//! `__kernel_cos`, and the quadrant `n mod 4` picks which of the two is the
//! sine and the signs. Each result is within 1 ulp of the correctly rounded
//! value, as fdlibm's are; the tests compare with the platform's `sin` and
//! `cos`. Larger, infinite and NaN arguments go to the platform's
//! functions.

// The constants are fdlibm's as published, digit for digit, so that a
// reader can check them against the source; they round to the same doubles.
#![allow(clippy::excessive_precision)]

/// `__kernel_sin` coefficients (fdlibm).
const S1: f64 = -1.666_666_666_666_663_243_48e-1;
const S2: f64 = 8.333_333_333_322_489_461_24e-3;
const S3: f64 = -1.984_126_982_985_794_931_34e-4;
const S4: f64 = 2.755_731_370_707_006_767_89e-6;
const S5: f64 = -2.505_076_025_340_686_341_95e-8;
const S6: f64 = 1.589_690_995_211_550_102_21e-10;
/// `__kernel_cos` coefficients (fdlibm).
const C1: f64 = 4.166_666_666_666_660_190_37e-2;
const C2: f64 = -1.388_888_888_887_410_957_49e-3;
const C3: f64 = 2.480_158_728_947_672_941_78e-5;
const C4: f64 = -2.755_731_435_139_066_330_35e-7;
const C5: f64 = 2.087_572_321_298_174_827_90e-9;
const C6: f64 = -1.135_964_755_778_819_482_65e-11;
/// `1.5 · 2⁵²`: adding and subtracting it rounds to an integer.
const TO_INT: f64 = 1.5 / f64::EPSILON;
/// `2/π` rounded (fdlibm's `invpio2`, 0x3FE45F306DC9C883).
const INV_PIO2: f64 = std::f64::consts::FRAC_2_PI;
/// `π/2` in parts of 33 bits (`PIO2_k`) and their tails (`PIO2_kT`).
const PIO2_1: f64 = 1.570_796_326_734_125_614_17;
const PIO2_1T: f64 = 6.077_100_506_506_192_249_32e-11;
const PIO2_2: f64 = 6.077_100_506_303_965_976_60e-11;
const PIO2_2T: f64 = 2.022_266_248_795_950_631_54e-21;
const PIO2_3: f64 = 2.022_266_248_711_166_455_80e-21;
const PIO2_3T: f64 = 8.478_427_660_368_899_569_97e-32;
/// The high word of `2²⁰·π/2`: the reduction is exact below it.
const MEDIUM_LIMIT: u32 = 0x4139_21fb;
/// The high word of `2⁻²⁷`: below it `sin x` rounds to `x` and `cos x` to 1
/// (fdlibm's tests are `2⁻²⁶` and `2⁻²⁷·√2`).
const TINY_LIMIT: u32 = 0x3e40_0000;

/// `(sin x, cos x)`, each within 1 ulp of the exact value.
#[inline(never)]
pub fn sin_cos(x: f64) -> (f64, f64) {
    let ix = (x.to_bits() >> 32) as u32 & 0x7fff_ffff;
    if ix < TINY_LIMIT {
        // What the kernels round to, at once: an angle that stays at zero
        // (the robot's heading) is common.
        return (x, 1.0);
    }
    if ix >= MEDIUM_LIMIT {
        return platform_sin_cos(x);
    }
    let (n, y, tail) = reduce(x);
    let (s, c) = (kernel_sin(y, tail), kernel_cos(y, tail));
    // Quadrant n: sin x = (s, c, −s, −c)[n mod 4] and
    // cos x = (c, −s, −c, s)[n mod 4], the swap and the signs as bits.
    let (sin, cos) = if n & 1 == 0 { (s, c) } else { (c, s) };
    let sign_sin = ((n as u64) & 2) << 62;
    let sign_cos = (((n + 1) as u64) & 2) << 62;
    (f64::from_bits(sin.to_bits() ^ sign_sin), f64::from_bits(cos.to_bits() ^ sign_cos))
}

/// `sin x`: the sine [`sin_cos`] returns, bit for bit, from its reduction
/// and only the kernel polynomial the quadrant needs. Generated code calls
/// it for a sine without its cosine, so that a body computing a subset of
/// another's outputs (the end point's momentum and constraint, without the
/// forces that pair the angle) returns the same bits as the whole body.
#[inline(never)]
pub fn sin(x: f64) -> f64 {
    let ix = (x.to_bits() >> 32) as u32 & 0x7fff_ffff;
    if ix < TINY_LIMIT {
        return x;
    }
    if ix >= MEDIUM_LIMIT {
        return platform_sin_cos(x).0;
    }
    let (n, y, tail) = reduce(x);
    // sin x = (s, c, −s, −c)[n mod 4].
    let value = if n & 1 == 0 { kernel_sin(y, tail) } else { kernel_cos(y, tail) };
    f64::from_bits(value.to_bits() ^ (((n as u64) & 2) << 62))
}

/// `cos x`: the cosine [`sin_cos`] returns, bit for bit (see [`sin`]).
#[inline(never)]
pub fn cos(x: f64) -> f64 {
    let ix = (x.to_bits() >> 32) as u32 & 0x7fff_ffff;
    if ix < TINY_LIMIT {
        return 1.0;
    }
    if ix >= MEDIUM_LIMIT {
        return platform_sin_cos(x).1;
    }
    let (n, y, tail) = reduce(x);
    // cos x = (c, −s, −c, s)[n mod 4].
    let value = if n & 1 == 0 { kernel_cos(y, tail) } else { kernel_sin(y, tail) };
    f64::from_bits(value.to_bits() ^ ((((n + 1) as u64) & 2) << 62))
}

/// How many sine–cosine pairs of one body a [`SinCosMemo`] keeps (the
/// generated code gives the first this many pair arguments of a system a
/// slot each; further pairs are computed at every call).
pub const SIN_COS_SLOTS: usize = 4;

/// The latest sine–cosine pair of each slot with its argument, kept at one
/// evaluation point (`StageValues::sin_cos_memo`) from one evaluation to the
/// next: a Newton iteration evaluates the same point again and again, and
/// an angle its updates leave unchanged to the last bit (the skate's
/// heading, whose equation is linear; Lobatto's first stage point, which is
/// the step's start) needs no new argument reduction and polynomials.
/// Keyed by the argument's bits, so a hit returns exactly what [`sin_cos`]
/// would: the memo changes no result. A cache, not part of any value: two
/// memos always compare equal.
#[derive(Clone, Copy, Debug)]
pub struct SinCosMemo {
    /// `(x.to_bits(), sin x, cos x)` per slot.
    entries: [(u64, f64, f64); SIN_COS_SLOTS],
}

impl Default for SinCosMemo {
    /// Every slot holds the pair of `+0`, which [`sin_cos`] returns as
    /// `(0, 1)`: a valid entry, so no slot needs a flag.
    fn default() -> Self {
        SinCosMemo { entries: [(0, 0.0, 1.0); SIN_COS_SLOTS] }
    }
}

impl PartialEq for SinCosMemo {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl SinCosMemo {
    /// `(sin x, cos x)`, from slot `slot` when it holds `x` (bit for bit),
    /// otherwise computed by [`sin_cos`] and kept there. A slot past
    /// [`SIN_COS_SLOTS`] keeps nothing.
    #[inline(always)]
    pub fn sin_cos(&mut self, slot: usize, x: f64) -> (f64, f64) {
        let Some(entry) = self.entries.get_mut(slot) else { return sin_cos(x) };
        if entry.0 == x.to_bits() {
            return (entry.1, entry.2);
        }
        let (s, c) = sin_cos(x);
        *entry = (x.to_bits(), s, c);
        (s, c)
    }
}

/// Large, infinite or NaN arguments: the platform's reduction, out of the
/// common path.
#[cold]
#[inline(never)]
fn platform_sin_cos(x: f64) -> (f64, f64) {
    x.sin_cos()
}

/// `x = n·π/2 + (y + tail)` with `|y| ≤ π/4` (nearly: `n` is rounded to
/// nearest), for `|x| < 2²⁰·π/2`: fdlibm's rounds, the second and third
/// only where the one before cancelled more than 16, then 49 bits of `x`'s
/// exponent.
#[inline(always)]
fn reduce(x: f64) -> (i64, f64, f64) {
    let f_n = (x * INV_PIO2 + TO_INT) - TO_INT;
    let n = f_n as i64;
    let ex = exponent(x);
    let mut r = x - f_n * PIO2_1;
    let mut w = f_n * PIO2_1T;
    let mut y = r - w;
    if ex - exponent(y) > 16 {
        (r, w, y) = further_rounds(f_n, ex, r);
    }
    (n, y, (r - y) - w)
}

/// The second and, where it cancels too, third round of the reduction,
/// from the first round's remainder `r1`.
#[cold]
#[inline(never)]
fn further_rounds(f_n: f64, ex: i64, r1: f64) -> (f64, f64, f64) {
    let t = f_n * PIO2_2;
    let r = r1 - t;
    let w = f_n * PIO2_2T - ((r1 - r) - t);
    let y = r - w;
    if ex - exponent(y) <= 49 {
        return (r, w, y);
    }
    let t = f_n * PIO2_3;
    let r3 = r - t;
    let w = f_n * PIO2_3T - ((r - r3) - t);
    (r3, w, r3 - w)
}

/// The biased exponent of `y`: how many bits a round of the reduction
/// cancelled is `exponent(x) − exponent(y)`.
#[inline(always)]
fn exponent(y: f64) -> i64 {
    ((y.to_bits() >> 52) & 0x7ff) as i64
}

/// `sin(x + y)` for `|x| ≤ π/4`, `y` the tail of `x` (fdlibm's
/// `__kernel_sin` with a tail).
#[inline(always)]
fn kernel_sin(x: f64, y: f64) -> f64 {
    let z = x * x;
    let w = z * z;
    let r = S2 + z * (S3 + z * S4) + z * w * (S5 + z * S6);
    let v = z * x;
    x - ((z * (0.5 * y - v * r) - y) - v * S1)
}

/// `cos(x + y)` for `|x| ≤ π/4` (fdlibm's `__kernel_cos`).
#[inline(always)]
fn kernel_cos(x: f64, y: f64) -> f64 {
    let z = x * x;
    let w = z * z;
    let r = z * (C1 + z * (C2 + z * C3)) + w * w * (C4 + z * (C5 + z * C6));
    let hz = 0.5 * z;
    let w = 1.0 - hz;
    w + (((1.0 - w) - hz) + (z * r - x * y))
}

#[cfg(test)]
mod tests {
    use super::{cos, sin, sin_cos, SinCosMemo, SIN_COS_SLOTS};
    use crate::linalg::test_matrices::random_values;

    /// Distance in units in the last place (0 for equal values, NaN
    /// included, and for `±0`).
    fn ulps(a: f64, b: f64) -> u64 {
        if a == b || (a.is_nan() && b.is_nan()) {
            return 0;
        }
        (a.to_bits() as i64).abs_diff(b.to_bits() as i64)
    }

    /// The larger of the sine's and the cosine's distances from the
    /// platform's; the lone [`sin`] and [`cos`] equal the pair's bit for
    /// bit.
    fn distance(x: f64) -> u64 {
        let (s, c) = sin_cos(x);
        assert_eq!((sin(x).to_bits(), cos(x).to_bits()), (s.to_bits(), c.to_bits()), "x = {x:e}");
        ulps(s, x.sin()).max(ulps(c, x.cos()))
    }

    /// Within 1 ulp of the platform's `sin` and `cos` (themselves within
    /// 1 ulp of the exact value) on a million arguments in [−100, 100],
    /// 200 000 up to the range limit, and the 200 doubles around each of
    /// 4000 multiples of π/2, where the first and second rounds of the
    /// reduction cancel.
    #[test]
    fn sine_and_cosine_are_within_one_ulp_of_the_platforms() {
        let mut args: Vec<f64> = random_values(0x2545_f491_4f6c_dd1d, 1_000_000).iter().map(|u| u * 100.0).collect();
        args.extend(random_values(0x9e37_79b9_7f4a_7c15, 200_000).iter().map(|u| u * 1.6e6));
        for k in -2000i64..2000 {
            let m = k as f64 * std::f64::consts::FRAC_PI_2;
            args.extend((-100i64..100).map(|d| f64::from_bits(m.to_bits().wrapping_add_signed(d))));
        }
        let (worst, at) = args.iter().map(|&x| (distance(x), x)).fold((0, 0.0), |a, b| if b.0 > a.0 { b } else { a });
        assert!(worst <= 1, "{worst} ulps at x = {at:e}");
        let differ = args.iter().filter(|&&x| distance(x) > 0).count();
        assert!(differ < args.len() / 20, "{differ} of {} differ from the platform's", args.len());
    }

    /// The memo returns the computed pair bit for bit, from every slot, for
    /// a repeated argument, a changed one, the default entry's `+0` and
    /// `−0`, and NaN (whose bits match themselves but whose pair is NaN
    /// anyway); a slot past the last keeps nothing and still computes.
    #[test]
    fn the_memo_returns_what_sin_cos_computes() {
        let bits = |(s, c): (f64, f64)| (s.to_bits(), c.to_bits());
        let mut memo = SinCosMemo::default();
        let args = [0.0, -0.0, 0.3, 0.3, 1e-9, 2.5, 2.5, -7.25, f64::NAN, f64::NAN, 1e7, 0.0];
        for slot in 0..SIN_COS_SLOTS + 1 {
            for &x in &args {
                assert_eq!(bits(memo.sin_cos(slot, x)), bits(sin_cos(x)), "slot {slot}, x = {x:e}");
            }
        }
        // Two slots keep their own arguments.
        let mut memo = SinCosMemo::default();
        for &x in &args {
            assert_eq!(bits(memo.sin_cos(0, x)), bits(sin_cos(x)));
            assert_eq!(bits(memo.sin_cos(1, -x)), bits(sin_cos(-x)));
        }
        assert_eq!(memo, SinCosMemo::default(), "memos compare equal whatever they hold");
    }

    #[test]
    fn special_arguments_keep_their_values() {
        for x in [1e-300, -1e-300, 5e-324, 1e-8, 0.785, 2.357, 1e300, -1e300, 1.7e6, f64::MAX] {
            assert!(distance(x) <= 1, "x = {x:e}");
        }
        assert_eq!(sin_cos(0.0).0.to_bits(), 0.0f64.to_bits());
        assert_eq!(sin_cos(-0.0).0.to_bits(), (-0.0f64).to_bits());
        assert_eq!(sin_cos(0.0).1, 1.0);
        // Either side of the tiny-argument bound: the kernels' values.
        let bound = f64::from_bits(0x3e40_0000_0000_0000);
        for x in [bound, f64::from_bits(bound.to_bits() - 1), -bound, 1e-20] {
            assert_eq!(sin_cos(x), (x.sin(), x.cos()), "x = {x:e}");
        }
        for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let (s, c) = sin_cos(x);
            assert!(s.is_nan() && c.is_nan(), "x = {x}");
        }
    }
}
