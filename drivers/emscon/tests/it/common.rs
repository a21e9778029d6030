//! Test harness: a simulator server on an ephemeral loopback port.

use std::net::SocketAddr;
use std::sync::{Arc, MutexGuard};
use std::time::Duration;

use emscon::{
    serve_with_options, Client, ClientConfig, FaultConfig, ServerOptions, SharedFaults,
    SimpleBackend, SimpleState, StationarySetup,
};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

/// Measuring time used by the tests (ms).
pub const MEAS_MS: i32 = 20;

/// A running simulator.
pub struct Sim {
    pub addr: SocketAddr,
    pub backend: Arc<SimpleBackend>,
    pub faults: SharedFaults,
    stop: Option<oneshot::Sender<()>>,
    handle: Option<JoinHandle<std::io::Result<()>>>,
}

impl Sim {
    pub async fn start() -> Sim {
        Self::start_with(SimpleState::default()).await
    }

    pub async fn start_with(state: SimpleState) -> Sim {
        Self::start_with_options(state, ServerOptions::default()).await
    }

    /// A simulator with `opts` (its busy grace shortened for the tests).
    pub async fn start_with_options(state: SimpleState, opts: ServerOptions) -> Sim {
        let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let addr = listener.local_addr().expect("addr");
        let backend = Arc::new(SimpleBackend::new(state));
        let faults = FaultConfig::shared();
        let (tx, rx) = oneshot::channel::<()>();
        let opts = ServerOptions {
            busy_grace: Duration::from_millis(150),
            ..opts
        };
        let handle = tokio::spawn(serve_with_options(
            listener,
            backend.clone(),
            faults.clone(),
            opts,
            async move {
                let _ = rx.await;
            },
        ));
        Sim {
            addr,
            backend,
            faults,
            stop: Some(tx),
            handle: Some(handle),
        }
    }

    pub fn faults(&self) -> MutexGuard<'_, FaultConfig> {
        self.faults.lock().expect("faults lock")
    }

    pub async fn client(&self) -> Client {
        self.client_with(fast_config()).await
    }

    pub async fn client_with(&self, cfg: ClientConfig) -> Client {
        Client::connect(self.addr, cfg).await.expect("connect")
    }

    /// A client after the full stationary setup.
    pub async fn ready_client(&self) -> Client {
        self.ready_client_with(fast_config()).await
    }

    pub async fn ready_client_with(&self, cfg: ClientConfig) -> Client {
        let c = self.client_with(cfg).await;
        c.setup_stationary(&setup()).await.expect("setup");
        c
    }

    pub async fn stop(mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        if let Some(h) = self.handle.take() {
            let r = tokio::time::timeout(Duration::from_secs(5), h).await;
            assert!(matches!(r, Ok(Ok(Ok(())))), "server did not stop cleanly");
        }
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
    }
}

/// Short timeouts so fault tests stay fast.
pub fn fast_config() -> ClientConfig {
    ClientConfig {
        connect_timeout: Duration::from_secs(2),
        command_timeout: Duration::from_millis(400),
        initialize_timeout: Duration::from_secs(2),
        search_timeout: Duration::from_millis(400),
        measure_margin: Duration::from_millis(300),
        ..ClientConfig::default()
    }
}

pub fn setup() -> StationarySetup {
    StationarySetup {
        meas_time_ms: MEAS_MS,
        ..StationarySetup::default()
    }
}
