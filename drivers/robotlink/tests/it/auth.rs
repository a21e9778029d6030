//! Protocol v3 access: only a client that proves it holds the shared secret, from an allowed
//! address, gets anything but `HELLO`, `AUTH` and `STOP` answered; the client checks the
//! server's proof too (PROTOCOL.md §3a).

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::time::Duration;

use robotlink::{
    ClientConfig, Nonce, Proof, RobotBackend, RobotClient, RobotError, ServerAccess, SharedSecret,
    SimpleConfig,
};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

use crate::common::{secret, Harness, Raw, SECRET_HEX};

fn other_secret() -> SharedSecret {
    SharedSecret::from_hex(&"ab".repeat(32), "other").unwrap()
}

/// The backend has not been powered and has not moved.
fn untouched(h: &Harness) {
    assert!(!h.backend.power(), "arm power was switched on");
    assert!(!h.backend.is_moving(), "the arm moves");
    assert_eq!(h.backend.joints_deg(), [0.0; 6], "the arm moved");
}

#[tokio::test]
async fn a_stranger_is_refused_before_any_power_or_motion() {
    // The probe of issue 17: HELLO, POWER ON, MOVEJ 90 0 0 0 0 0 from a client without the
    // secret. Each way of trying ends before power or motion, with the connection closed.
    let h = Harness::start().await;
    for hello in ["1 HELLO 2", "1 HELLO 1", "1 HELLO 3"] {
        let mut s = Raw::connect(&h).await;
        let l = s.exchange(hello).await;
        if hello == "1 HELLO 3" {
            assert!(l.starts_with("1 OK "), "{l}");
        } else {
            // an old client is told what to do
            assert!(l.starts_with("1 ERR E_ARGS"), "{l}");
            assert!(l.contains("v3") && l.contains("secret_file"), "{l}");
        }
        let l = s.exchange("2 POWER ON").await;
        assert!(l.starts_with("2 ERR E_AUTH"), "{l}");
        assert!(s.closed().await, "open after a refused POWER ON");
        untouched(&h);
        let mut s = Raw::connect(&h).await;
        s.exchange(hello).await;
        let l = s.exchange("2 MOVEJ 90 0 0 0 0 0").await;
        assert!(l.starts_with("2 ERR E_AUTH"), "{l}");
        assert!(s.closed().await);
        untouched(&h);
    }
    // Nothing but the handshake and STOP is answered: not even what the arm is.
    for line in [
        "1 PING",
        "1 STATE",
        "1 JOINTS",
        "1 POSE",
        "1 SPEED 10",
        "1 WAIT 10",
    ] {
        let mut s = Raw::connect(&h).await;
        let l = s.exchange(line).await;
        assert!(l.starts_with("1 ERR E_AUTH"), "{line}: {l}");
        assert!(s.closed().await);
    }
    untouched(&h);
    h.stop().await;
}

#[tokio::test]
async fn a_wrong_or_replayed_proof_is_refused_and_closes() {
    let h = Harness::start().await;
    // A guessed proof.
    let mut s = Raw::connect(&h).await;
    s.exchange("1 HELLO 3").await;
    let l = s
        .exchange(&format!("2 AUTH {} {}", "0".repeat(32), "0".repeat(64)))
        .await;
    assert!(l.starts_with("2 ERR E_AUTH authentication failed"), "{l}");
    assert!(s.closed().await);
    // AUTH without a challenge.
    let mut s = Raw::connect(&h).await;
    let l = s
        .exchange(&format!("1 AUTH {} {}", "0".repeat(32), "0".repeat(64)))
        .await;
    assert!(l.starts_with("1 ERR E_AUTH"), "{l}");
    assert!(s.closed().await);
    // A real client's handshake, recorded, replayed on the next connection.
    let mut s = Raw::connect(&h).await;
    let ns = s.exchange("1 HELLO 3").await["1 OK ".len()..].to_string();
    let ns = Nonce::from_hex(&ns).unwrap();
    let nc = Nonce::generate().unwrap();
    let auth = format!(
        "2 AUTH {} {}",
        nc.to_hex(),
        secret().client_proof(&ns, &nc).to_hex()
    );
    let ok = s.exchange(&auth).await;
    assert!(ok.starts_with("2 OK "), "{ok}");
    // the server proved it holds the secret too
    let sp = Proof::from_hex(ok.rsplit(' ').next().unwrap()).unwrap();
    assert!(secret().verify_server(&ns, &nc, &sp));
    drop(s);
    let mut replay = None;
    for _ in 0..50 {
        let mut r = Raw::connect(&h).await;
        let l = r.exchange("1 HELLO 3").await;
        if let Some(fresh) = l.strip_prefix("1 OK ") {
            assert_ne!(fresh, ns.to_hex(), "a fresh nonce per connection");
            replay = Some(r);
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let mut r = replay.expect("a new connection once the first ended");
    let l = r.exchange(&auth).await;
    assert!(
        l.starts_with("2 ERR E_AUTH"),
        "replayed proof accepted: {l}"
    );
    assert!(r.closed().await);
    // A proof is spent with its challenge: a second AUTH after a failed one never happens
    // (closed), and after a good one is refused as already authenticated.
    let mut s = connect_authenticated(&h).await;
    let l = s.exchange(&auth.replacen("2 ", "3 ", 1)).await;
    assert!(l.starts_with("3 ERR E_ARGS already authenticated"), "{l}");
    untouched(&h);
    h.stop().await;
}

async fn connect_authenticated(h: &Harness) -> Raw {
    for _ in 0..50 {
        let mut s = Raw::connect(h).await;
        if s.authenticate(&secret()).await.starts_with("2 OK ") {
            return s;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("no authenticated connection");
}

#[tokio::test]
async fn a_client_with_another_secret_or_none_gets_a_clear_error() {
    let h = Harness::start().await;
    let c = RobotClient::connect(
        h.addr,
        ClientConfig {
            secret: Some(other_secret()),
            ..Harness::config()
        },
    )
    .await
    .unwrap();
    let e = c.hello().await.unwrap_err();
    assert!(matches!(e, RobotError::Auth(_)), "{e:?}");
    let text = e.to_string();
    assert!(
        text.contains("refused cellcal's proof") && text.contains("secret_file"),
        "{text}"
    );
    assert!(matches!(c.power(true).await, Err(RobotError::Disconnected)));
    untouched(&h);
    let c = RobotClient::connect(
        h.addr,
        ClientConfig {
            secret: None,
            ..Harness::config()
        },
    )
    .await
    .unwrap();
    let e = c.hello().await.unwrap_err().to_string();
    assert!(e.contains("no shared secret configured"), "{e}");
    untouched(&h);
    h.stop().await;
}

#[tokio::test]
async fn the_client_refuses_a_server_that_cannot_prove_the_secret() {
    // A fake controller: it answers HELLO with a nonce and accepts any AUTH, but does not hold
    // the secret. The client must not go on (it would believe that server's joints).
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let fake = tokio::spawn(async move {
        let (s, _) = listener.accept().await.unwrap();
        let (rd, mut wr) = s.into_split();
        let mut rd = BufReader::new(rd);
        let mut lines = Vec::new();
        loop {
            let mut l = String::new();
            if rd.read_line(&mut l).await.unwrap_or(0) == 0 {
                break;
            }
            let seq = l.split_whitespace().next().unwrap_or("0").to_string();
            let reply = if l.contains(" HELLO ") {
                format!("{seq} OK {}\n", Nonce::generate().unwrap().to_hex())
            } else if l.contains(" AUTH ") {
                format!("{seq} OK CS9 TX2-90 fake {}\n", "1f".repeat(32))
            } else {
                format!("{seq} OK\n")
            };
            lines.push(l);
            wr.write_all(reply.as_bytes()).await.unwrap();
        }
        lines
    });
    let c = RobotClient::connect(addr, Harness::config()).await.unwrap();
    let e = c.hello().await.unwrap_err();
    assert!(matches!(e, RobotError::Auth(_)), "{e:?}");
    assert!(e.to_string().contains("did not prove"), "{e}");
    assert!(c.is_closed());
    assert!(matches!(c.power(true).await, Err(RobotError::Disconnected)));
    drop(c);
    let lines = tokio::time::timeout(Duration::from_secs(2), fake)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(lines.len(), 2, "only the handshake was sent: {lines:?}");
}

#[tokio::test]
async fn the_client_refuses_an_older_server_clearly() {
    let h = Harness::start().await;
    h.faults().max_proto_version = 2;
    let c = h.client().await;
    let e = c.hello().await.unwrap_err();
    assert!(matches!(e, RobotError::OldServer(_)), "{e:?}");
    let text = e.to_string();
    assert!(
        text.contains("without authentication") && text.contains("deploy/staubli"),
        "{text}"
    );
    assert_eq!(c.protocol_version(), None);
    untouched(&h);
    h.stop().await;
}

#[tokio::test]
async fn only_allowed_addresses_get_a_session() {
    // The whole 127/8 is loopback on Linux: a client bound to 127.0.0.2 is a second host.
    let access = ServerAccess {
        allow: vec![IpAddr::V4(Ipv4Addr::new(127, 0, 0, 1))],
        ..ServerAccess::loopback(secret())
    };
    let h = Harness::with_access(SimpleConfig::default(), access).await;
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.bind(SocketAddr::from(([127, 0, 0, 2], 0))).unwrap();
    let mut s = Raw::from_stream(sock.connect(h.addr).await.unwrap());
    assert_eq!(s.recv().await, "* EVT REFUSED address not allowed");
    assert!(s.closed().await);
    // even with the secret
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.bind(SocketAddr::from(([127, 0, 0, 2], 0))).unwrap();
    let c = RobotClient::from_stream(sock.connect(h.addr).await.unwrap(), Harness::config());
    let e = c.hello().await.unwrap_err();
    assert!(e.to_string().contains("address not allowed"), "{e}");
    untouched(&h);
    // the allowed address is served
    let c = h.ready_client().await;
    c.ping().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn an_unauthenticated_connection_cannot_hold_the_one_client_slot() {
    let access = ServerAccess {
        auth_timeout: Duration::from_millis(300),
        ..ServerAccess::loopback(secret())
    };
    let h = Harness::with_access(SimpleConfig::default(), access).await;
    let mut idle = Raw::connect(&h).await;
    assert_eq!(idle.recv().await, "* EVT REFUSED authentication timeout");
    assert!(idle.closed().await);
    // cellcal gets the controller after it
    let c = h.ready_client().await;
    // and an authenticated session has no such timeout
    tokio::time::sleep(Duration::from_millis(500)).await;
    c.ping().await.unwrap();
    h.stop().await;
}

#[test]
fn no_debug_output_shows_the_secret() {
    let cfg = Harness::config();
    for shown in [
        format!("{cfg:?}"),
        format!("{:?}", ServerAccess::loopback(secret())),
        format!("{:?}", secret()),
    ] {
        assert!(!shown.to_lowercase().contains(&SECRET_HEX[..16]), "{shown}");
        assert!(!shown.contains("92, 15, 30"), "{shown}"); // its first bytes as decimals
    }
}
