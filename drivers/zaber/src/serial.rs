//! Opening real serial ports (and pty slaves) with tokio-serial.

use tokio_serial::{DataBits, FlowControl, Parity, SerialPortBuilderExt, SerialStream, StopBits};

/// Serial line settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SerialSettings {
    /// Baud rate.
    pub baud: u32,
    /// Data bits (7 or 8).
    pub data_bits: DataBits,
    /// Parity.
    pub parity: Parity,
    /// Stop bits.
    pub stop_bits: StopBits,
}

impl SerialSettings {
    /// Zaber ASCII: `baud` 8N1 (default 115200).
    pub fn zaber(baud: u32) -> Self {
        Self {
            baud,
            data_bits: DataBits::Eight,
            parity: Parity::None,
            stop_bits: StopBits::One,
        }
    }

    /// Sylvac Opto-RS232 cable: 4800 7E2.
    pub fn sylvac() -> Self {
        Self {
            baud: 4800,
            data_bits: DataBits::Seven,
            parity: Parity::Even,
            stop_bits: StopBits::Two,
        }
    }

    /// Generic 9600 8N1.
    pub fn generic_9600() -> Self {
        Self::zaber(9600)
    }
}

/// Open `path` as an async serial port, no flow control. Works on `/dev/ttyUSB*` and on a
/// pty slave (`/dev/pts/N`).
pub fn open_port(path: &str, s: &SerialSettings) -> std::io::Result<SerialStream> {
    tokio_serial::new(path, s.baud)
        .data_bits(s.data_bits)
        .parity(s.parity)
        .stop_bits(s.stop_bits)
        .flow_control(FlowControl::None)
        .open_native_async()
        .map_err(std::io::Error::from)
}
