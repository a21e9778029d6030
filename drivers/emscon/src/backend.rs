//! The physics seam of the simulator server: [`TrackerBackend`] plus a simple fixed-point
//! implementation ([`SimpleBackend`]) for tests.

use std::sync::{Mutex, MutexGuard};

use crate::types::ReflectorInfo;

/// Meteorological values as reported in results.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Meteo {
    /// Air temperature in °C.
    pub temperature_c: f64,
    /// Air pressure in mbar.
    pub pressure_mbar: f64,
    /// Relative humidity in %.
    pub humidity_pct: f64,
}

impl Default for Meteo {
    fn default() -> Self {
        Meteo {
            temperature_c: 20.0,
            pressure_mbar: 1013.25,
            humidity_pct: 45.0,
        }
    }
}

/// One simulated point in mm (tracker frame, RHR).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BackendPoint {
    /// X, Y, Z in mm.
    pub xyz_mm: [f64; 3],
    /// Standard deviations in mm.
    pub std_mm: [f64; 3],
    /// Total standard deviation in mm.
    pub std_total_mm: f64,
    /// Meteo at the time of the measurement.
    pub meteo: Meteo,
}

/// Outcome of a simulated stationary measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BackendMeasurement {
    /// A point was measured.
    Point(BackendPoint),
    /// The target was lost during the measurement (reported like a beam break).
    TargetLost,
}

/// Physics supplied to the simulator server (noise, drift and world model live here).
pub trait TrackerBackend: Send + Sync {
    /// Measures one stationary point averaged over `meas_time_ms`.
    fn measure(&self, meas_time_ms: i32) -> BackendMeasurement;
    /// True if a reflector is physically visible to the tracker.
    fn reflector_found(&self) -> bool;
    /// True if a visible reflector is within the lock-on (capture) radius of `xyz_mm`
    /// (tracker frame), where GoPosition / GoLastMeasuredPoint point the beam. The default
    /// has no geometry: any visible reflector.
    fn reflector_near(&self, xyz_mm: [f64; 3]) -> bool {
        let _ = xyz_mm;
        self.reflector_found()
    }
    /// Current meteo values.
    fn meteo(&self) -> Meteo;
    /// Initial "initialised" state of the tracker when the server starts.
    fn initialized(&self) -> bool {
        false
    }
    /// True if the laser is warmed up (otherwise StartMeasurement fails with 10012).
    fn warmed_up(&self) -> bool {
        true
    }
    /// Reflectors known to the tracker.
    fn reflectors(&self) -> Vec<ReflectorInfo> {
        default_reflectors()
    }
    /// Tracker serial number.
    fn serial_number(&self) -> i32 {
        960_001
    }
}

/// A default reflector list: RRR 1.5" (id 1), BRR 1.5" (id 2), RRR 0.5" (id 3).
pub fn default_reflectors() -> Vec<ReflectorInfo> {
    let list = [
        (1, 5, 19.05, "RRR 1.5in"),
        (2, 7, 19.05, "BRR 1.5in"),
        (3, 6, 6.35, "RRR 0.5in"),
    ];
    list.iter()
        .map(|(id, tt, off, name)| ReflectorInfo {
            total: 3,
            id: *id,
            target_type: *tt,
            surface_offset: *off,
            name: (*name).to_string(),
        })
        .collect()
}

/// How far from the point a GoPosition / GoLastMeasuredPoint aims at the simulated tracker
/// still locks onto the reflector (mm): the order of an AT960's PowerLock field at a few metres.
pub const CAPTURE_RADIUS_MM: f64 = 25.0;

/// Mutable state of [`SimpleBackend`].
#[derive(Debug, Clone, PartialEq)]
pub struct SimpleState {
    /// Point returned by every measurement (mm).
    pub xyz_mm: [f64; 3],
    /// Standard deviations returned (mm).
    pub std_mm: [f64; 3],
    /// Meteo returned.
    pub meteo: Meteo,
    /// Reflector visible.
    pub reflector_found: bool,
    /// Initial initialised state.
    pub initialized: bool,
    /// Laser warmed up.
    pub warmed_up: bool,
    /// The next N measurements lose the target.
    pub target_lost_next: u32,
    /// Number of measurements taken.
    pub measurements: u64,
}

impl Default for SimpleState {
    fn default() -> Self {
        SimpleState {
            xyz_mm: [1000.0, 2000.0, 300.0],
            std_mm: [0.005, 0.005, 0.008],
            meteo: Meteo::default(),
            reflector_found: true,
            initialized: false,
            warmed_up: true,
            target_lost_next: 0,
            measurements: 0,
        }
    }
}

/// Deterministic backend returning a fixed point; state is editable through [`SimpleBackend::state`].
#[derive(Debug, Default)]
pub struct SimpleBackend {
    state: Mutex<SimpleState>,
}

impl SimpleBackend {
    /// Backend with the given initial state.
    pub fn new(state: SimpleState) -> Self {
        SimpleBackend {
            state: Mutex::new(state),
        }
    }
    /// Locks the state for reading or editing.
    pub fn state(&self) -> MutexGuard<'_, SimpleState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl TrackerBackend for SimpleBackend {
    fn measure(&self, _meas_time_ms: i32) -> BackendMeasurement {
        let mut s = self.state();
        s.measurements += 1;
        if s.target_lost_next > 0 {
            s.target_lost_next -= 1;
            return BackendMeasurement::TargetLost;
        }
        let [a, b, c] = s.std_mm;
        BackendMeasurement::Point(BackendPoint {
            xyz_mm: s.xyz_mm,
            std_mm: s.std_mm,
            std_total_mm: (a * a + b * b + c * c).sqrt(),
            meteo: s.meteo,
        })
    }
    fn reflector_found(&self) -> bool {
        self.state().reflector_found
    }
    fn reflector_near(&self, xyz_mm: [f64; 3]) -> bool {
        let s = self.state();
        let d2: f64 = (0..3).map(|i| (s.xyz_mm[i] - xyz_mm[i]).powi(2)).sum();
        s.reflector_found && d2.sqrt() <= CAPTURE_RADIUS_MM
    }
    fn meteo(&self) -> Meteo {
        self.state().meteo
    }
    fn initialized(&self) -> bool {
        self.state().initialized
    }
    fn warmed_up(&self) -> bool {
        self.state().warmed_up
    }
}
