//! Wall-clock time as the store keeps it: milliseconds since the Unix epoch.

use std::time::{SystemTime, UNIX_EPOCH};

/// `t` in milliseconds since the Unix epoch (0 for a time before it).
pub fn unix_ms(t: SystemTime) -> i64 {
    t.duration_since(UNIX_EPOCH)
        .map(|d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
        .unwrap_or(0)
}

/// Now, in milliseconds since the Unix epoch.
pub fn now_unix_ms() -> i64 {
    unix_ms(SystemTime::now())
}

/// `t` as people read it: local ISO 8601 with the offset, to the second,
/// `2026-11-26T11:05:07+01:00` (the zone of `TZ`, else `/etc/localtime`, else UTC).
/// (A stand-in for `units::human::fmt_local_time`, same name and signature.)
pub fn fmt_local_time(t: SystemTime) -> String {
    fmt_time_in(t, &jiff::tz::TimeZone::system())
}

/// `ms` since the Unix epoch as [`fmt_local_time`] writes it.
pub fn local_text(ms: i64) -> String {
    let t = match u64::try_from(ms) {
        Ok(ms) => UNIX_EPOCH + std::time::Duration::from_millis(ms),
        Err(_) => UNIX_EPOCH - std::time::Duration::from_millis(ms.unsigned_abs()),
    };
    fmt_local_time(t)
}

/// `t` in the zone `tz`, as [`fmt_local_time`] writes it (seconds cut).
fn fmt_time_in(t: SystemTime, tz: &jiff::tz::TimeZone) -> String {
    match jiff::Timestamp::try_from(t) {
        Ok(ts) => ts
            .to_zoned_datetime(tz.clone())
            .strftime("%Y-%m-%dT%H:%M:%S%:z")
            .to_string(),
        // beyond the years −9999…9999
        Err(_) => format!("{} ms after the Unix epoch", unix_ms(t)),
    }
}

/// `ms` since the Unix epoch as an ISO 8601 UTC time, `2024-05-01T12:34:56Z` (seconds cut).
pub fn utc_text(ms: i64) -> String {
    let secs = ms.div_euclid(1000);
    let (days, day_secs) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // civil date from days since 1970-01-01 (H. Hinnant's algorithm, proleptic Gregorian)
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        day_secs / 3600,
        day_secs % 3600 / 60,
        day_secs % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_text_names_the_civil_date_and_time() {
        assert_eq!(utc_text(0), "1970-01-01T00:00:00Z");
        // 2000-02-29 (a leap day of a century leap year) 23:59:59.999
        assert_eq!(utc_text(951_868_799_999), "2000-02-29T23:59:59Z");
        assert_eq!(utc_text(1_700_000_000_000), "2023-11-14T22:13:20Z");
        assert_eq!(utc_text(-1), "1969-12-31T23:59:59Z");
    }

    #[test]
    fn local_times_carry_their_offset_to_the_second() {
        let t = UNIX_EPOCH + std::time::Duration::from_millis(1_795_666_135_248);
        let utc = jiff::tz::TimeZone::UTC;
        assert_eq!(fmt_time_in(t, &utc), "2026-11-26T04:08:55+00:00");
        let cet = jiff::tz::TimeZone::posix("CET-1CEST,M3.5.0,M10.5.0/3").unwrap();
        assert_eq!(fmt_time_in(t, &cet), "2026-11-26T05:08:55+01:00");
        let summer = UNIX_EPOCH + std::time::Duration::from_secs(1_785_000_000);
        assert_eq!(fmt_time_in(summer, &cet), "2026-07-25T19:20:00+02:00");
        let st_johns = jiff::tz::TimeZone::posix("NST3:30").unwrap();
        assert_eq!(fmt_time_in(t, &st_johns), "2026-11-26T00:38:55-03:30");
    }
}
