//! Which device facts give millimetres per microstep.
//!
//! A Zaber stepper axis reports its microstep **resolution** (`get resolution`: microsteps per
//! full motor step, 64 by default on X-series) and its identity (`get device.id` for the
//! device, `get peripheral.id` for the axis). The **full-step size** (mm of carriage travel per
//! full motor step: lead-screw pitch / steps per revolution, e.g. 0.6096 mm / 200 = 0.003048 mm
//! on LSM-type lead screws) is a property of the product that no ASCII setting reports; it is
//! looked up here by identity. So:
//!
//! `mm per microstep = full_step_mm(device.id, peripheral.id) / resolution`.
//!
//! To use a real stage, read `get device.id` and `get peripheral.id` on it and add a row with
//! the full-step size from its datasheet (microstep size × 64 for a datasheet that quotes the
//! default 64-microstep size). The table holds only products whose facts were checked.

/// One product whose full-step size is known.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Product {
    /// `device.id` of the device (controller or integrated stage).
    pub device_id: u32,
    /// `peripheral.id` of the axis; 0 matches any (integrated products).
    pub peripheral_id: u32,
    /// Display name.
    pub name: &'static str,
    /// Carriage travel per full motor step (mm).
    pub full_step_mm: f64,
}

/// The device simulated by [`crate::sim::StageSim`]: cellcal's own ids (not a Zaber catalogue
/// entry), with an LSM-type lead screw (0.6096 mm per rev, 200 steps per rev).
pub const SIM_PRODUCT: Product = Product {
    device_id: 99_001,
    peripheral_id: 99_101,
    name: "cellcal simulated X-series lead-screw stage",
    full_step_mm: 0.003_048,
};

/// Products whose full-step size is known (see the module doc to add one).
pub const KNOWN_PRODUCTS: &[Product] = &[SIM_PRODUCT];

/// The known product with this identity (exact peripheral first, then an integrated row).
pub fn lookup(device_id: u32, peripheral_id: u32) -> Option<&'static Product> {
    KNOWN_PRODUCTS
        .iter()
        .find(|p| p.device_id == device_id && p.peripheral_id == peripheral_id)
        .or_else(|| {
            KNOWN_PRODUCTS
                .iter()
                .find(|p| p.device_id == device_id && p.peripheral_id == 0)
        })
}

/// Microsteps per mm of a product at `resolution` microsteps per full step.
pub fn microsteps_per_mm(product: &Product, resolution: u32) -> f64 {
    f64::from(resolution) / product.full_step_mm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_product_at_64_is_the_lsm_microstep() {
        let p = lookup(SIM_PRODUCT.device_id, SIM_PRODUCT.peripheral_id).unwrap();
        let k = microsteps_per_mm(p, 64);
        assert!((1.0 / k - 0.000_047_625).abs() < 1e-15, "{k}");
        assert!(lookup(SIM_PRODUCT.device_id, 1).is_none());
        assert!(lookup(1, SIM_PRODUCT.peripheral_id).is_none());
    }
}
