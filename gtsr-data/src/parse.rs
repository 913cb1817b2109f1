//! Parsers for command-line values (`clap`'s `value_parser`), shared by the settings of every
//! crate: a number with its range checked, the error saying what was expected and given.

use std::fmt::Display;
use std::str::FromStr;

/// Parses `s` as `T` and keeps it where `ok` holds for its value as `f64`; otherwise the error
/// says the value `must be {expected}`.
fn parse_checked<T>(s: &str, ok: impl Fn(f64) -> bool, expected: &str) -> Result<T, String>
where
    T: FromStr + Copy + Into<f64>,
    T::Err: Display,
{
    let v: T = s.parse().map_err(|e| format!("{e}"))?;
    if ok(v.into()) {
        Ok(v)
    } else {
        Err(format!("must be {expected}, got {s}"))
    }
}

/// Parses a finite number `>= 0` (`f32` or `f64`).
pub fn parse_non_negative<T>(s: &str) -> Result<T, String>
where
    T: FromStr + Copy + Into<f64>,
    T::Err: Display,
{
    parse_checked(s, |v| v.is_finite() && v >= 0.0, "a finite number >= 0")
}

/// Parses a finite number `> 0` (`f32` or `f64`).
pub fn parse_positive<T>(s: &str) -> Result<T, String>
where
    T: FromStr + Copy + Into<f64>,
    T::Err: Display,
{
    parse_checked(s, |v| v.is_finite() && v > 0.0, "a finite number > 0")
}

/// Parses a number in `[0, 1]` (`f32` or `f64`).
pub fn parse_unit<T>(s: &str) -> Result<T, String>
where
    T: FromStr + Copy + Into<f64>,
    T::Err: Display,
{
    parse_checked(s, |v| (0.0..=1.0).contains(&v), "in [0, 1]")
}

/// Parses a number in the open interval `(0, 1)` (`f32` or `f64`).
pub fn parse_open_unit<T>(s: &str) -> Result<T, String>
where
    T: FromStr + Copy + Into<f64>,
    T::Err: Display,
{
    parse_checked(s, |v| v > 0.0 && v < 1.0, "in (0, 1)")
}

/// Parses a count `>= 1`.
pub fn parse_count(s: &str) -> Result<usize, String> {
    let v: usize = s.parse().map_err(|e| format!("{e}"))?;
    if v >= 1 {
        Ok(v)
    } else {
        Err(format!("must be at least 1, got {s}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_are_checked_and_named() {
        assert_eq!(parse_positive::<f32>("0.5"), Ok(0.5));
        assert_eq!(
            parse_positive::<f64>("0"),
            Err("must be a finite number > 0, got 0".into())
        );
        assert_eq!(parse_non_negative::<f64>("0"), Ok(0.0));
        assert!(parse_non_negative::<f32>("inf").is_err());
        assert!(parse_non_negative::<f32>("-1").is_err());
        assert_eq!(parse_unit::<f64>("1"), Ok(1.0));
        assert_eq!(
            parse_unit::<f32>("1.5"),
            Err("must be in [0, 1], got 1.5".into())
        );
        assert!(parse_open_unit::<f64>("1").is_err());
        assert_eq!(parse_open_unit::<f64>("0.25"), Ok(0.25));
        assert_eq!(parse_count("3"), Ok(3));
        assert_eq!(parse_count("0"), Err("must be at least 1, got 0".into()));
        assert!(parse_positive::<f64>("x").is_err());
    }
}
