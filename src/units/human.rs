//! Numbers and times for people, one format for every CLI table, message and report:
//! lengths in mm and small angles in mrad with 3 decimals (μm, μrad), large angles in degrees
//! with 3 decimals, never e-notation, a value that is not a number shown as `—`, a value that
//! rounds to zero shown as `0.000` (never `-0.000`); times as local ISO 8601 with the offset, to
//! the second; durations as `1 h 05 min`, `4 min 10 s`, `21.8 s`.
//!
//! The functions give the number only; the caller writes the unit once, in the column header
//! or after the number (`format!("{} mm", fmt_mm(x))`). Angles come in rad (the unit inside).
//! Machine formats (JSON, CSV, TOML) do not use this module: they keep full precision.

use std::time::Duration;

pub use jiff::tz::TimeZone;

/// What a value that is not a finite number shows.
pub const NO_NUMBER: &str = "—";

/// `v` with `decimals` decimals, no exponent; `—` when not finite; a value that rounds to zero
/// without its sign (`0.000`, never `-0.000`).
pub fn fmt_fixed(v: f64, decimals: usize) -> String {
    if !v.is_finite() {
        return NO_NUMBER.to_owned();
    }
    let s = format!("{v:.decimals$}");
    match s.strip_prefix('-') {
        Some(rest) if rest.bytes().all(|b| b == b'0' || b == b'.') => rest.to_owned(),
        _ => s,
    }
}

/// `v` with 3 decimals ([`fmt_fixed`]).
fn fixed3(v: f64) -> String {
    fmt_fixed(v, 3)
}

/// A length in mm (given in mm), 3 decimals: `-122.248`.
pub fn fmt_mm(mm: f64) -> String {
    fixed3(mm)
}

/// A small angle (given in rad) in mrad, 3 decimals: `0.120` for 1.2e-4 rad.
pub fn fmt_mrad(rad: f64) -> String {
    fixed3(rad * 1e3)
}

/// A large angle (given in rad) in degrees, 3 decimals: `90.000` for π/2.
pub fn fmt_deg(rad: f64) -> String {
    fixed3(rad.to_degrees())
}

/// Three lengths in mm: `(0.320, -12.000, 95.500)`.
pub fn fmt_mm3(mm: &[f64; 3]) -> String {
    format!("({}, {}, {})", fmt_mm(mm[0]), fmt_mm(mm[1]), fmt_mm(mm[2]))
}

/// `v` with `digits` significant digits and no exponent, for a figure without a fixed
/// resolution (a solver cost): `0.02288` for 2.288e-2 and 4 digits; `—` when not finite.
pub fn fmt_sig(v: f64, digits: u32) -> String {
    if !v.is_finite() {
        return NO_NUMBER.to_owned();
    }
    if v == 0.0 {
        return "0".to_owned();
    }
    let magnitude = v.abs().log10().floor() as i64;
    let decimals = (i64::from(digits) - 1 - magnitude).max(0) as usize;
    format!("{v:.decimals$}")
}

/// A value and its σ in one format: `fmt_pm(fmt_mm, -0.122, 0.0021)` is `-0.122 ± 0.002`.
pub fn fmt_pm(format: fn(f64) -> String, value: f64, sigma: f64) -> String {
    format!("{} ± {}", format(value), format(sigma))
}

/// A duration: `21.8 s` below a minute, `4 min 10 s` below an hour, `1 h 05 min` from an hour.
pub fn fmt_duration(d: Duration) -> String {
    let s = d.as_secs_f64();
    if (s * 10.0).round() < 600.0 {
        return format!("{s:.1} s");
    }
    let secs = s.round() as u64;
    if secs < 3600 {
        return format!("{} min {:02} s", secs / 60, secs % 60);
    }
    let mins = (s / 60.0).round() as u64;
    format!("{} h {:02} min", mins / 60, mins % 60)
}

/// What [`fmt_estimate`] says of a planned duration above 0 s that would round to 0 s.
pub const UNDER_TEN_S: &str = "under 10 s";

/// A planned duration (s), as precise as a plan can be: whole minutes above 10 min (`3 h 10
/// min`, `43 min`), else to 10 s (`4 min 10 s`, `1 min`, `40 s`), [`UNDER_TEN_S`] for a
/// duration that would round to 0 s but is not none, `0 s` for none; `—` when not a number.
pub fn fmt_estimate(secs: f64) -> String {
    if !secs.is_finite() || secs < 0.0 {
        return NO_NUMBER.to_owned();
    }
    if secs > 0.0 && secs < 5.0 {
        return UNDER_TEN_S.to_owned();
    }
    if secs > 600.0 {
        let mins = (secs / 60.0).round() as u64;
        return if mins >= 60 {
            format!("{} h {:02} min", mins / 60, mins % 60)
        } else {
            format!("{mins} min")
        };
    }
    let tens = (secs / 10.0).round() as u64 * 10;
    match (tens / 60, tens % 60) {
        (0, s) => format!("{s} s"),
        (m, 0) => format!("{m} min"),
        (m, s) => format!("{m} min {s:02} s"),
    }
}

/// `unix_ms` (ms since the Unix epoch) in the system's time zone (`TZ`, else /etc/localtime,
/// else UTC), ISO 8601 to the second with the offset: `2026-11-26T12:05:07+01:00`.
pub fn fmt_local_time(unix_ms: i64) -> String {
    fmt_time_in(unix_ms, &local_time_zone())
}

/// The system's time zone (`TZ`, else /etc/localtime, else UTC), for [`fmt_time_in`].
pub fn local_time_zone() -> TimeZone {
    TimeZone::system()
}

/// `unix_ms` in `tz`, ISO 8601 to the second with the offset (seconds cut, not rounded); `—`
/// outside the range of civil time.
pub fn fmt_time_in(unix_ms: i64, tz: &TimeZone) -> String {
    match jiff::Timestamp::from_second(unix_ms.div_euclid(1000)) {
        Ok(t) => t
            .to_zoned_datetime(tz.clone())
            .strftime("%Y-%m-%dT%H:%M:%S%:z")
            .to_string(),
        Err(_) => NO_NUMBER.to_owned(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_and_angles_round_to_three_decimals_without_e_notation() {
        assert_eq!(fmt_mm(-0.1222478), "-0.122");
        assert_eq!(fmt_mm(-122.2478), "-122.248");
        assert_eq!(fmt_mm(0.0005), "0.001", "half rounds away from zero here");
        assert_eq!(fmt_mm(1.0e-9), "0.000");
        assert_eq!(fmt_mm(1.0e9), "1000000000.000");
        assert_eq!(fmt_mm(0.3195619813344486), "0.320");
        assert_eq!(fmt_mrad(1.2e-4), "0.120");
        assert_eq!(fmt_mrad(-3.4567e-3), "-3.457");
        assert_eq!(fmt_deg(std::f64::consts::FRAC_PI_2), "90.000");
        assert_eq!(fmt_deg(-std::f64::consts::PI), "-180.000");
        for v in [1e-30, 1e30, -7.5e-12, 123456.789] {
            for s in [fmt_mm(v), fmt_mrad(v), fmt_deg(v)] {
                assert!(!s.contains('e'), "{v}: {s}");
            }
        }
    }

    #[test]
    fn negative_zero_shows_as_zero_and_no_number_as_a_dash() {
        assert_eq!(fmt_mm(-0.0), "0.000");
        assert_eq!(fmt_mm(-0.0004), "0.000");
        assert_eq!(fmt_mrad(-1e-7), "0.000");
        assert_eq!(fmt_deg(-1e-9), "0.000");
        assert_eq!(fmt_mm(-0.0005), "-0.001");
        assert_eq!(fmt_fixed(-0.0000001, 6), "0.000000");
        assert_eq!(fmt_fixed(-0.4, 0), "0");
        assert_eq!(fmt_fixed(-2.5e-7, 6), "0.000000");
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(fmt_mm(v), "—");
            assert_eq!(fmt_mrad(v), "—");
            assert_eq!(fmt_deg(v), "—");
        }
        assert_eq!(fmt_pm(fmt_mm, f64::NAN, 0.001), "— ± 0.001");
    }

    #[test]
    fn values_carry_their_sigma_and_vectors_their_parts() {
        assert_eq!(fmt_pm(fmt_mm, -0.1222478, 0.00214), "-0.122 ± 0.002");
        assert_eq!(fmt_pm(fmt_mrad, 2.5e-4, 1.1e-5), "0.250 ± 0.011");
        assert_eq!(
            fmt_mm3(&[0.3195619813344486, -12.0, 95.49951]),
            "(0.320, -12.000, 95.500)"
        );
    }

    #[test]
    fn significant_digits_never_use_an_exponent() {
        assert_eq!(fmt_sig(2.288143e-2, 4), "0.02288");
        assert_eq!(fmt_sig(1.5e-9, 2), "0.0000000015");
        assert_eq!(fmt_sig(123456.7, 4), "123457");
        assert_eq!(fmt_sig(0.0, 4), "0");
        assert_eq!(fmt_sig(f64::NAN, 4), "—");
    }

    #[test]
    fn durations_read_as_seconds_minutes_or_hours() {
        let s = Duration::from_secs_f64;
        assert_eq!(fmt_duration(s(0.0)), "0.0 s");
        assert_eq!(fmt_duration(s(21.84)), "21.8 s");
        assert_eq!(fmt_duration(s(59.94)), "59.9 s");
        assert_eq!(fmt_duration(s(59.96)), "1 min 00 s");
        assert_eq!(fmt_duration(s(250.0)), "4 min 10 s");
        assert_eq!(fmt_duration(s(3599.4)), "59 min 59 s");
        assert_eq!(fmt_duration(s(3599.6)), "1 h 00 min");
        assert_eq!(fmt_duration(s(3900.0)), "1 h 05 min");
        assert_eq!(fmt_duration(s(26.0 * 3600.0 + 59.0 * 60.0)), "26 h 59 min");
    }

    #[test]
    fn estimates_give_minutes_from_ten_minutes_on_else_tens_of_seconds() {
        assert_eq!(
            fmt_estimate(3.0 * 3600.0 + 10.0 * 60.0 + 29.0),
            "3 h 10 min"
        );
        assert_eq!(fmt_estimate(3.0 * 3600.0 + 5.0 * 60.0), "3 h 05 min");
        assert_eq!(fmt_estimate(3599.0), "1 h 00 min");
        assert_eq!(fmt_estimate(600.5), "10 min");
        assert_eq!(fmt_estimate(600.0), "10 min");
        assert_eq!(fmt_estimate(596.0), "10 min");
        assert_eq!(fmt_estimate(594.0), "9 min 50 s");
        assert_eq!(fmt_estimate(254.0), "4 min 10 s");
        assert_eq!(fmt_estimate(44.9), "40 s");
        assert_eq!(fmt_estimate(5.0), "10 s");
        assert_eq!(fmt_estimate(4.9), "under 10 s", "not \"0 s\"");
        assert_eq!(fmt_estimate(0.01), "under 10 s");
        assert_eq!(fmt_estimate(0.0), "0 s", "nothing at all");
        assert_eq!(fmt_estimate(f64::NAN), "—");
    }

    #[test]
    fn times_are_iso_8601_to_the_second_with_the_offset() {
        let utc = TimeZone::UTC;
        // 2026-11-26T11:05:07.999Z: the milliseconds are cut
        let t = 1_795_691_107_999;
        assert_eq!(fmt_time_in(t, &utc), "2026-11-26T11:05:07+00:00");
        let berlin = TimeZone::posix("CET-1CEST,M3.5.0,M10.5.0/3").expect("POSIX TZ");
        assert_eq!(fmt_time_in(t, &berlin), "2026-11-26T12:05:07+01:00");
        // summer time
        assert_eq!(
            fmt_time_in(1_782_900_000_000, &berlin),
            "2026-07-01T12:00:00+02:00"
        );
        let ny = TimeZone::posix("EST5EDT,M3.2.0,M11.1.0").expect("POSIX TZ");
        assert_eq!(fmt_time_in(-1, &ny), "1969-12-31T18:59:59-05:00");
        assert_eq!(fmt_time_in(i64::MAX, &utc), "—");
        // the system's zone: the same instant, some offset
        let local = fmt_local_time(t);
        assert_eq!(local.len(), "2026-11-26T11:05:07+00:00".len(), "{local}");
    }
}
