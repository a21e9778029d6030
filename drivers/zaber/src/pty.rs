//! Pseudo-terminal pair: the simulator runs on the master, the client opens the slave path
//! (`/dev/pts/N`) with tokio-serial exactly like a USB serial adapter.
//!
//! Working configuration (Linux): `openpty`, slave put in raw mode (`cfmakeraw`) and kept open by
//! this crate for the lifetime of the pair (so the master never sees EIO/hang-up when a client
//! closes and reopens the slave), master set non-blocking and driven through tokio's `AsyncFd`.
//! serialport then opens the slave path, sets TIOCEXCL and its termios (baud is accepted and
//! ignored by the pty driver, parity/data bits are stored).

use std::io;
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::PathBuf;
use std::pin::Pin;
use std::task::{Context, Poll};

use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::task::JoinHandle;

use crate::sim::{serve_gauge, serve_stage, GaugeSim, StageSim};

/// Async master side of a pty.
#[derive(Debug)]
pub struct PtyMaster {
    fd: AsyncFd<OwnedFd>,
}

/// A pty pair: async master plus the slave's path (the slave fd is held open internally).
#[derive(Debug)]
pub struct PtyPair {
    /// Master side (the device end).
    pub master: PtyMaster,
    /// Path of the slave device, e.g. `/dev/pts/3` (the host end).
    pub slave_path: PathBuf,
    /// Held open so that client close/reopen never hangs up the master.
    _slave: OwnedFd,
}

fn nix_io(e: nix::Error) -> io::Error {
    io::Error::from_raw_os_error(e as i32)
}

impl PtyPair {
    /// Open a new pty pair (must be called inside a tokio runtime).
    pub fn open() -> io::Result<Self> {
        let pty = nix::pty::openpty(None, None).map_err(nix_io)?;
        let mut t = tcgetattr(pty.slave.as_fd()).map_err(nix_io)?;
        cfmakeraw(&mut t);
        tcsetattr(pty.slave.as_fd(), SetArg::TCSANOW, &t).map_err(nix_io)?;
        let slave_path = std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd()))?;
        let flags = fcntl(pty.master.as_raw_fd(), FcntlArg::F_GETFL).map_err(nix_io)?;
        let flags = OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK;
        fcntl(pty.master.as_raw_fd(), FcntlArg::F_SETFL(flags)).map_err(nix_io)?;
        // SAFETY: `register` requires that the fd stays open and is not closed behind the
        // registration's back. We move the `OwnedFd` into the `AsyncFd`, which owns it, deregisters
        // it on drop and only then closes it; nobody else holds this descriptor.
        let fd = unsafe { AsyncFd::register(pty.master) }.map_err(io::Error::from)?;
        Ok(Self {
            master: PtyMaster { fd },
            slave_path,
            _slave: pty.slave,
        })
    }
}

impl AsyncRead for PtyMaster {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut guard = match self.fd.poll_read_ready(cx) {
                Poll::Ready(Ok(g)) => g,
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Pending => return Poll::Pending,
            };
            let unfilled = buf.initialize_unfilled();
            match guard
                .try_io(|fd| nix::unistd::read(fd.get_ref().as_raw_fd(), unfilled).map_err(nix_io))
            {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                // EIO: no slave open (cannot happen while we hold the slave); report EOF.
                Ok(Err(e)) if e.raw_os_error() == Some(libc_eio()) => return Poll::Ready(Ok(())),
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

fn libc_eio() -> i32 {
    nix::errno::Errno::EIO as i32
}

impl AsyncWrite for PtyMaster {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = match self.fd.poll_write_ready(cx) {
                Poll::Ready(Ok(g)) => g,
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Pending => return Poll::Pending,
            };
            match guard.try_io(|fd| nix::unistd::write(fd.get_ref(), data).map_err(nix_io)) {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

/// A simulator running on the master of a pty; open `slave_path` to talk to it.
#[derive(Debug)]
pub struct PtyDevice {
    /// Path of the slave device to open with tokio-serial.
    pub slave_path: PathBuf,
    task: JoinHandle<io::Result<()>>,
}

impl PtyDevice {
    /// Slave path as a string (for `ZaberStage::open` / `GaugeClient::open`).
    pub fn path(&self) -> String {
        self.slave_path.to_string_lossy().into_owned()
    }

    /// Stop the simulator.
    pub fn shutdown(self) {
        self.task.abort();
    }
}

impl Drop for PtyDevice {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Start a simulated Zaber stage on a new pty; returns its slave path.
pub fn spawn_stage_pty(sim: StageSim) -> io::Result<PtyDevice> {
    let pair = PtyPair::open()?;
    let slave_path = pair.slave_path.clone();
    let master = pair.master;
    let keep = pair._slave;
    let task = tokio::spawn(async move {
        let _keep = keep;
        serve_stage(master, sim).await
    });
    Ok(PtyDevice { slave_path, task })
}

/// Start a simulated gauge on a new pty; returns its slave path.
pub fn spawn_gauge_pty(sim: GaugeSim) -> io::Result<PtyDevice> {
    let pair = PtyPair::open()?;
    let slave_path = pair.slave_path.clone();
    let master = pair.master;
    let keep = pair._slave;
    let task = tokio::spawn(async move {
        let _keep = keep;
        serve_gauge(master, sim).await
    });
    Ok(PtyDevice { slave_path, task })
}
