use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use robotlink::{
    serve, ClientConfig, FaultConfig, FaultHandle, RobotBackend, RobotClient, SimpleBackend,
    SimpleConfig,
};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

pub struct Harness {
    pub addr: SocketAddr,
    pub backend: Arc<SimpleBackend>,
    pub faults: FaultHandle,
    shutdown: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<std::io::Result<()>>>,
}

impl Harness {
    pub async fn start() -> Self {
        Self::with_config(SimpleConfig {
            max_joint_speed_deg_s: 600.0,
            settle_time: Duration::from_millis(20),
            ..Default::default()
        })
        .await
    }

    pub async fn with_config(cfg: SimpleConfig) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let backend = Arc::new(SimpleBackend::new(cfg));
        let faults = FaultConfig::handle();
        let (tx, rx) = oneshot::channel::<()>();
        let dynb: Arc<dyn RobotBackend> = backend.clone();
        let task = tokio::spawn(serve(listener, dynb, faults.clone(), async move {
            let _ = rx.await;
        }));
        Self {
            addr,
            backend,
            faults,
            shutdown: Some(tx),
            task: Some(task),
        }
    }

    pub fn config() -> ClientConfig {
        ClientConfig {
            connect_timeout: Duration::from_secs(2),
            request_timeout: Duration::from_millis(1000),
            wait_margin: Duration::from_millis(500),
            event_capacity: 16,
        }
    }

    pub async fn client(&self) -> RobotClient {
        RobotClient::connect(self.addr, Self::config())
            .await
            .unwrap()
    }

    /// Connected client with power on and the handshake done.
    pub async fn ready_client(&self) -> RobotClient {
        let c = self.client().await;
        c.hello().await.unwrap();
        c.power(true).await.unwrap();
        c
    }

    pub fn faults(&self) -> std::sync::MutexGuard<'_, FaultConfig> {
        self.faults.lock().unwrap()
    }

    pub async fn stop(mut self) {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.task.take() {
            tokio::time::timeout(Duration::from_secs(3), t)
                .await
                .expect("server did not shut down")
                .unwrap()
                .unwrap();
        }
    }
}

/// Poll `cond` every 5 ms for up to `within`.
pub async fn eventually(within: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let end = tokio::time::Instant::now() + within;
    while tokio::time::Instant::now() < end {
        if cond() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    cond()
}

pub fn close(a: &[f64; 6], b: &[f64; 6], tol: f64) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}
