use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use robotlink::{
    serve, ClientConfig, FaultConfig, FaultHandle, RobotBackend, RobotClient, ServerAccess,
    SharedSecret, SimpleBackend, SimpleConfig,
};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
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
        Self::with_access(cfg, ServerAccess::loopback(secret())).await
    }

    pub async fn with_access(cfg: SimpleConfig, access: ServerAccess) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let backend = Arc::new(SimpleBackend::new(cfg));
        let faults = FaultConfig::handle();
        let (tx, rx) = oneshot::channel::<()>();
        let dynb: Arc<dyn RobotBackend> = backend.clone();
        let task = tokio::spawn(serve(listener, dynb, faults.clone(), access, async move {
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
            secret: Some(secret()),
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

/// The test cell's shared secret (the server's and [`Harness::config`]'s).
pub const SECRET_HEX: &str = "5c0f1e2d3c4b5a69788796a5b4c3d2e1f00112233445566778899aabbccddeef";

pub fn secret() -> SharedSecret {
    SharedSecret::from_hex(SECRET_HEX, "test").unwrap()
}

/// A raw line connection to a server, for speaking the protocol by hand.
pub struct Raw {
    pub rd: BufReader<tokio::net::tcp::OwnedReadHalf>,
    pub wr: tokio::net::tcp::OwnedWriteHalf,
}

impl Raw {
    pub async fn connect(h: &Harness) -> Raw {
        Raw::from_stream(tokio::net::TcpStream::connect(h.addr).await.unwrap())
    }

    pub fn from_stream(s: tokio::net::TcpStream) -> Raw {
        let (rd, wr) = s.into_split();
        Raw {
            rd: BufReader::new(rd),
            wr,
        }
    }

    pub async fn send(&mut self, line: &str) {
        self.wr.write_all(line.as_bytes()).await.unwrap();
        self.wr.write_all(b"\n").await.unwrap();
    }

    /// The next line; "" at EOF.
    pub async fn recv(&mut self) -> String {
        let mut l = String::new();
        tokio::time::timeout(Duration::from_secs(2), self.rd.read_line(&mut l))
            .await
            .expect("a line within 2 s")
            .unwrap();
        l.trim_end().to_string()
    }

    /// The next line, asserted to start with `prefix`.
    pub async fn expect(&mut self, prefix: &str) {
        let l = self.recv().await;
        assert!(l.starts_with(prefix), "expected {prefix:?}, got {l:?}");
    }

    pub async fn exchange(&mut self, line: &str) -> String {
        self.send(line).await;
        self.recv().await
    }

    /// True when the server has closed the connection (EOF within 2 s, nothing else sent).
    pub async fn closed(&mut self) -> bool {
        self.recv().await.is_empty()
    }

    /// The v3 handshake by hand with `secret` as seq 1 and 2; the AUTH reply line.
    pub async fn authenticate(&mut self, secret: &SharedSecret) -> String {
        let hello = self.exchange("1 HELLO 3").await;
        let ns = hello.strip_prefix("1 OK ").expect(&hello);
        let ns = robotlink::Nonce::from_hex(ns).expect(ns);
        let nc = robotlink::Nonce::generate().unwrap();
        let proof = secret.client_proof(&ns, &nc);
        self.exchange(&format!("2 AUTH {} {}", nc.to_hex(), proof.to_hex()))
            .await
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
