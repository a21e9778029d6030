// cellcal cockpit: the one format of numbers and times the page shows (the rules of
// src/units/human.rs): lengths in mm with 3 decimals (μm), small angles in mrad with 3 decimals
// (μrad), large angles in degrees with 3 decimals, never e-notation; identified values with
// their σ; times as local ISO 8601 with the offset, to the second; durations as `1 h 05 min`,
// `4 min 10 s`, `21.8 s`. app.js formats every number through `human`; "—" stands for no
// number (null, NaN, ±∞).
'use strict';

const human = (() => {
  const finite = (x) => typeof x === 'number' && Number.isFinite(x);
  const pad = (n) => String(n).padStart(2, '0');
  /** `x` with `digits` decimals, never `-0.000` (a value that rounds to zero has no sign). */
  const fixed = (x, digits) => {
    if (!finite(x)) return '—';
    const t = x.toFixed(digits);
    return /^-0\.?0*$/.test(t) ? t.slice(1) : t;
  };
  return Object.freeze({
    /** A length (mm): `-122.248`. */
    mm: (x) => fixed(x, 3),
    /** A small angle given in rad, in mrad: `0.123`. */
    mrad: (rad) => fixed(finite(rad) ? rad * 1000 : rad, 3),
    /** A large angle given in rad, in degrees: `90.000`. */
    deg: (rad) => fixed(finite(rad) ? (rad * 180) / Math.PI : rad, 3),
    /** A ratio with 2 decimals: `1.06`. */
    ratio: (x) => fixed(x, 2),
    /** `value ± sigma` of two formatted numbers; the value alone when σ is not known. */
    withSigma: (value, sigma) => (sigma === '—' || sigma == null ? value : value + ' ± ' + sigma),
    /** A duration (s): `21.8 s` under a minute, `4 min 10 s` under an hour, else `1 h 05 min`. */
    duration(s) {
      if (!finite(s) || s < 0) return '—';
      if (s < 59.95) return s.toFixed(1) + ' s';
      const whole = Math.round(s);
      if (whole < 3600) return Math.floor(whole / 60) + ' min ' + pad(whole % 60) + ' s';
      const minutes = Math.round(s / 60);
      return Math.floor(minutes / 60) + ' h ' + pad(minutes % 60) + ' min';
    },
    /** A time (ms since the Unix epoch) in the page's time zone: `2026-11-26T11:05:07+01:00`. */
    localTime(ms) {
      if (!finite(ms)) return '—';
      const d = new Date(ms);
      const off = -d.getTimezoneOffset();
      const sign = off < 0 ? '-' : '+';
      const a = Math.abs(off);
      return d.getFullYear() + '-' + pad(d.getMonth() + 1) + '-' + pad(d.getDate())
        + 'T' + pad(d.getHours()) + ':' + pad(d.getMinutes()) + ':' + pad(d.getSeconds())
        + sign + pad(Math.floor(a / 60)) + ':' + pad(a % 60);
    },
  });
})();
