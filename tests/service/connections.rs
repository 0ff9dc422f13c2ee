//! Slow and greedy clients (issue 9, item 2): a half-sent header and an idle kept-alive
//! connection are closed after their timeouts, a connection beyond `max_connections` gets a
//! 503 problem at once, idle sockets cannot keep `/healthz` from answering, and a trickled
//! upload ends at the overall upload deadline with 408.

use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use crate::service_common::*;

fn connect(s: &TestServer) -> TcpStream {
    let tcp = TcpStream::connect(s.base.trim_start_matches("http://")).unwrap();
    tcp.set_read_timeout(Some(Duration::from_secs(15))).unwrap();
    tcp
}

/// Reads until the server closes the connection; returns what it sent. Panics if the
/// connection is still open after the socket's read timeout.
fn read_until_closed(tcp: &mut TcpStream) -> String {
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match tcp.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == ErrorKind::ConnectionReset => break,
            Err(e) => panic!(
                "the server did not close the connection ({e}); got {:?}",
                String::from_utf8_lossy(&got)
            ),
        }
    }
    String::from_utf8_lossy(&got).into_owned()
}

/// `GET /healthz` on a fresh connection, retried until it answers 200 or `within` passes.
fn healthz_answers(s: &TestServer, within: Duration) {
    let end = Instant::now() + within;
    loop {
        let mut tcp = connect(s);
        let sent = tcp.write_all(b"GET /healthz HTTP/1.1\r\nHost: t\r\nConnection: close\r\n\r\n");
        let answer = if sent.is_ok() {
            read_until_closed(&mut tcp)
        } else {
            String::new()
        };
        if answer.starts_with("HTTP/1.1 200") {
            return;
        }
        assert!(
            Instant::now() < end,
            "/healthz still not answering: {answer:?}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn a_half_sent_header_is_disconnected_after_the_header_timeout() {
    let s = TestServer::start(|c| c.header_timeout_secs = 1);
    let mut tcp = connect(&s);
    tcp.write_all(b"GET /healthz HTTP/1.1\r\nHost: t\r\nX-Slow: ")
        .unwrap();
    let answer = read_until_closed(&mut tcp);
    assert!(!answer.contains("200"), "{answer}");
    // A client that never sends a byte is closed the same way.
    let mut silent = connect(&s);
    read_until_closed(&mut silent);
}

#[test]
fn an_idle_kept_alive_connection_is_closed_after_the_idle_timeout() {
    let s = TestServer::start(|c| c.idle_timeout_secs = 1);
    let mut tcp = connect(&s);
    tcp.write_all(b"GET /healthz HTTP/1.1\r\nHost: t\r\n\r\n")
        .unwrap();
    let answer = read_until_closed(&mut tcp);
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
}

#[test]
fn a_connection_beyond_the_cap_gets_503_and_healthz_recovers() {
    let s = TestServer::start(|c| {
        c.max_connections = 4;
        c.header_timeout_secs = 2;
    });
    // Four silent clients hold every slot.
    let mut holders: Vec<TcpStream> = (0..4).map(|_| connect(&s)).collect();
    std::thread::sleep(Duration::from_millis(300));
    let mut fifth = connect(&s);
    let _ = fifth.write_all(b"GET /healthz HTTP/1.1\r\nHost: t\r\n\r\n");
    let answer = read_until_closed(&mut fifth);
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
    let lower = answer.to_ascii_lowercase();
    assert!(
        lower.contains("content-type: application/problem+json"),
        "{answer}"
    );
    assert!(lower.contains("retry-after:"), "{answer}");
    assert!(
        answer.contains("/problems/too-many-connections"),
        "{answer}"
    );
    assert!(answer.contains("max_connections"), "{answer}");
    // The holders overstay the header timeout and are closed; the slots free up.
    for h in &mut holders {
        read_until_closed(h);
    }
    healthz_answers(&s, Duration::from_secs(15));
}

/// A connection from the local address `ip` (any of 127.0.0.0/8 reaches the loopback).
fn connect_from(s: &TestServer, ip: &str) -> TcpStream {
    use socket2::{Domain, Socket, Type};
    let sock = Socket::new(Domain::IPV4, Type::STREAM, None).unwrap();
    let local: std::net::SocketAddr = format!("{ip}:0").parse().unwrap();
    sock.bind(&local.into()).unwrap();
    let server: std::net::SocketAddr = s.base.trim_start_matches("http://").parse().unwrap();
    sock.connect(&server.into()).unwrap();
    let tcp: TcpStream = sock.into();
    tcp.set_read_timeout(Some(Duration::from_secs(15))).unwrap();
    tcp
}

#[test]
fn a_client_beyond_its_own_cap_gets_503_while_other_clients_are_served() {
    let s = TestServer::start(|c| {
        c.max_connections = 16;
        c.max_connections_per_client = 2;
        c.header_timeout_secs = 5;
    });
    // One client (127.0.0.1) holds its two slots with silent connections.
    let mut holders: Vec<TcpStream> = (0..2).map(|_| connect(&s)).collect();
    std::thread::sleep(Duration::from_millis(300));
    let mut third = connect(&s);
    let _ = third.write_all(b"GET /healthz HTTP/1.1\r\nHost: t\r\n\r\n");
    let answer = read_until_closed(&mut third);
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
    let lower = answer.to_ascii_lowercase();
    assert!(lower.contains("retry-after:"), "{answer}");
    assert!(
        answer.contains("/problems/too-many-client-connections"),
        "{answer}"
    );
    assert!(answer.contains("max_connections_per_client"), "{answer}");
    // Another address is served meanwhile (the global cap of 16 is far).
    let mut other = connect_from(&s, "127.0.0.2");
    other
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: t\r\nConnection: close\r\n\r\n")
        .unwrap();
    let answer = read_until_closed(&mut other);
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    // The first client closes one connection: it is served again at once (well before the
    // header timeout would have freed the slot).
    drop(holders.pop());
    healthz_answers(&s, Duration::from_secs(3));
}

#[test]
fn idle_sockets_beyond_the_cap_do_not_stop_healthz() {
    let s = TestServer::start(|c| {
        c.max_connections = 16;
        c.header_timeout_secs = 2;
    });
    let mut idle: Vec<TcpStream> = (0..216).map(|_| connect(&s)).collect();
    healthz_answers(&s, Duration::from_secs(15));
    // Every idle socket was closed by the server: refused at once beyond the cap, after the
    // header timeout within it.
    for tcp in &mut idle {
        read_until_closed(tcp);
    }
    healthz_answers(&s, Duration::from_secs(15));
}

#[test]
fn a_trickled_upload_ends_at_the_upload_deadline_with_408() {
    let s = TestServer::start(|c| {
        c.upload_timeout_secs = 2;
        c.body_timeout_secs = 30;
    });
    let mut tcp = connect(&s);
    let boundary = "trickleBoundary";
    let head = format!(
        "POST /v1/jobs HTTP/1.1\r\nHost: t\r\nContent-Type: multipart/form-data; boundary={boundary}\r\nContent-Length: 100000\r\n\r\n--{boundary}\r\nContent-Disposition: form-data; name=\"target\"; filename=\"t.glb\"\r\n\r\nglTF"
    );
    tcp.write_all(head.as_bytes()).unwrap();
    // A byte every 200 ms: never silent for body_timeout_secs, never done.
    let mut writer = tcp.try_clone().unwrap();
    let trickle = std::thread::spawn(move || {
        let end = Instant::now() + Duration::from_secs(20);
        while Instant::now() < end && writer.write_all(b"x").is_ok() {
            std::thread::sleep(Duration::from_millis(200));
        }
    });
    let mut answer = Vec::new();
    let mut buf = [0u8; 4096];
    while !String::from_utf8_lossy(&answer).contains('}') {
        match tcp.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => answer.extend_from_slice(&buf[..n]),
            Err(e) => panic!("no answer: {e}; got {:?}", String::from_utf8_lossy(&answer)),
        }
    }
    let text = String::from_utf8_lossy(&answer).into_owned();
    drop(tcp);
    trickle.join().unwrap();
    assert!(text.starts_with("HTTP/1.1 408"), "{text}");
    assert!(text.contains("/problems/upload-timeout"), "{text}");
    assert!(text.contains("upload_timeout_secs"), "{text}");
}
