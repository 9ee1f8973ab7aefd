//! A real S3 server for the object-store tests: moto (`python3 -m moto.server`, installed from PyPI by
//! scripts/install-test-deps.sh) on a free port, killed when its guard drops (also when a test fails);
//! a TCP proxy in front of it that a test can stop, as a store that goes away mid-build; an HTTP proxy
//! that answers 503 for as long as a test says, as a store with a transient outage; and a listener
//! that counts who calls it, standing in for a cloud's instance metadata address.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::process::{Child, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A running moto S3 server. Tests fail (never skip) when it cannot start.
pub struct Moto {
    child: Child,
    pub port: u16,
}

impl Moto {
    /// Starts `moto_server -H 127.0.0.1 -p 0` and reads the port it printed.
    pub fn start() -> Moto {
        let mut child = super::python_command()
            .args(["-m", "moto.server", "-H", "127.0.0.1", "-p", "0"])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start moto ({e}): run scripts/install-test-deps.sh (moto[s3], flask, flask-cors)"));
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut sent = false;
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if !sent {
                    if let Some(port) = line.split("http://127.0.0.1:").nth(1).and_then(|p| p.trim().parse::<u16>().ok()) {
                        let _ = tx.send(Ok(port));
                        sent = true;
                    } else if line.contains("Error") || line.contains("No module named") {
                        let _ = tx.send(Err(line));
                    }
                }
                // Keep draining, so the server never blocks on a full pipe.
            }
        });
        let mut guard = Moto { child, port: 0 };
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(Ok(port)) => guard.port = port,
            Ok(Err(line)) => panic!("moto did not start: {line} (run scripts/install-test-deps.sh)"),
            Err(_) => panic!("moto printed no port within 60 s (run scripts/install-test-deps.sh)"),
        }
        guard
    }

    pub fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// Creates a bucket with one plain `PUT /<bucket>`.
    pub fn create_bucket(&self, bucket: &str) {
        let status = http(self.port, "PUT", &format!("/{bucket}"), "");
        assert!(status.starts_with("HTTP/1.1 200") || status.starts_with("HTTP/1.0 200"), "creating bucket {bucket}: {status}");
    }

    /// The environment that points a `pointreggpt` process at this server through `endpoint`.
    pub fn vars(endpoint: &str) -> Vec<(&'static str, String)> {
        vec![
            ("AWS_ENDPOINT_URL", endpoint.to_string()),
            ("AWS_ACCESS_KEY_ID", "testing".into()),
            ("AWS_SECRET_ACCESS_KEY", "testing".into()),
            ("AWS_REGION", "us-east-1".into()),
            ("POINTREGGPT_STORE_RETRY_SECONDS", "3".into()),
        ]
    }

    /// Sets [`Moto::vars`] in this test process (hold [`ENV`] while doing so), after removing every
    /// inherited `AWS_*` variable ([`super::isolate_aws_env`]).
    pub fn set_env(&self) {
        super::isolate_aws_env();
        for (k, v) in Moto::vars(&self.endpoint()) {
            std::env::set_var(k, v);
        }
    }

    /// Turns on moto's authentication from now on: every request must be signed with a key made by IAM.
    pub fn require_auth(&self) {
        let status = http(self.port, "POST", "/moto-api/reset-auth", "0");
        assert!(status.contains(" 200"), "moto reset-auth: {status}");
    }

    /// Turns moto's authentication off again (any request is accepted), e.g. to list what a refused
    /// client left.
    pub fn end_auth(&self) {
        let status = http(self.port, "POST", "/moto-api/reset-auth", "inf");
        assert!(status.contains(" 200"), "moto reset-auth: {status}");
    }
}

impl Drop for Moto {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Serialises the tests that set the process environment for the in-process store client.
pub static ENV: Mutex<()> = Mutex::new(());

/// One HTTP/1.1 request without signature; returns the status line.
fn http(port: u16, method: &str, path: &str, body: &str) -> String {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    text.lines().next().unwrap_or_default().to_string()
}

/// A TCP proxy to `127.0.0.1:<target>`; [`Proxy::stop`] closes its port and every connection.
pub struct Proxy {
    pub port: u16,
    down: Arc<AtomicBool>,
    conns: Arc<Mutex<Vec<TcpStream>>>,
}

impl Proxy {
    pub fn start(target: u16) -> Proxy {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let port = listener.local_addr().unwrap().port();
        let down = Arc::new(AtomicBool::new(false));
        let conns: Arc<Mutex<Vec<TcpStream>>> = Arc::default();
        let (d, c) = (down.clone(), conns.clone());
        std::thread::spawn(move || {
            while !d.load(Ordering::SeqCst) {
                match listener.accept() {
                    Ok((client, _)) => {
                        client.set_nonblocking(false).unwrap();
                        let Ok(server) = TcpStream::connect(("127.0.0.1", target)) else { continue };
                        let mut list = c.lock().unwrap();
                        list.push(client.try_clone().unwrap());
                        list.push(server.try_clone().unwrap());
                        for (mut from, mut to) in [(client.try_clone().unwrap(), server.try_clone().unwrap()), (server, client)] {
                            std::thread::spawn(move || {
                                let _ = std::io::copy(&mut from, &mut to);
                                let _ = to.shutdown(Shutdown::Write);
                            });
                        }
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(2)),
                }
            }
        });
        Proxy { port, down, conns }
    }

    pub fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// The store goes away: the port closes and open connections are cut.
    pub fn stop(&self) {
        self.down.store(true, Ordering::SeqCst);
        for c in self.conns.lock().unwrap().iter() {
            let _ = c.shutdown(Shutdown::Both);
        }
        let t = Instant::now();
        while TcpStream::connect(("127.0.0.1", self.port)).is_ok() && t.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.stop();
    }
}

/// An HTTP proxy to `127.0.0.1:<target>` that serves one request per connection (it adds
/// `Connection: close` both ways) and, while [`HttpProxy::set_failing`] is on, answers every request
/// with `503 Service Unavailable` instead of forwarding it: a store with a transient outage, the kind
/// of error clients retry.
pub struct HttpProxy {
    pub port: u16,
    failing: Arc<AtomicBool>,
    down: Arc<AtomicBool>,
    /// Requests answered with 503.
    pub refused: Arc<AtomicUsize>,
    /// Requests forwarded to the server.
    pub forwarded: Arc<AtomicUsize>,
}

impl HttpProxy {
    pub fn start(target: u16) -> HttpProxy {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let port = listener.local_addr().unwrap().port();
        let proxy = HttpProxy {
            port,
            failing: Arc::default(),
            down: Arc::default(),
            refused: Arc::default(),
            forwarded: Arc::default(),
        };
        let (failing, down, refused, forwarded) = (proxy.failing.clone(), proxy.down.clone(), proxy.refused.clone(), proxy.forwarded.clone());
        std::thread::spawn(move || {
            while !down.load(Ordering::SeqCst) {
                match listener.accept() {
                    Ok((client, _)) => {
                        let (failing, refused, forwarded) = (failing.clone(), refused.clone(), forwarded.clone());
                        std::thread::spawn(move || {
                            let _ = client.set_nonblocking(false);
                            let _ = serve_one(client, target, &failing, &refused, &forwarded);
                        });
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(2)),
                }
            }
        });
        proxy
    }

    pub fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// From now on every request gets a 503 (`true`), or is forwarded again (`false`).
    pub fn set_failing(&self, failing: bool) {
        self.failing.store(failing, Ordering::SeqCst);
    }
}

impl Drop for HttpProxy {
    fn drop(&mut self) {
        self.down.store(true, Ordering::SeqCst);
    }
}

/// The message `bytes` (request or response) with its `Connection` headers replaced by `Connection: close`.
fn with_close(bytes: &[u8]) -> Vec<u8> {
    let Some(end) = bytes.windows(4).position(|w| w == b"\r\n\r\n") else { return bytes.to_vec() };
    let head = String::from_utf8_lossy(&bytes[..end]);
    let mut out: Vec<u8> = head
        .split("\r\n")
        .filter(|l| !l.to_ascii_lowercase().starts_with("connection:"))
        .flat_map(|l| [l.as_bytes(), b"\r\n"].concat())
        .collect();
    out.extend_from_slice(b"Connection: close\r\n\r\n");
    out.extend_from_slice(&bytes[end + 4..]);
    out
}

/// Reads one request (head and a `Content-Length` or chunked body) from `client`.
fn read_request(client: &mut TcpStream) -> std::io::Result<Vec<u8>> {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 65536];
    let end = loop {
        if let Some(end) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            break end + 4;
        }
        let n = client.read(&mut chunk)?;
        if n == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        buf.extend_from_slice(&chunk[..n]);
    };
    let head = String::from_utf8_lossy(&buf[..end]).to_ascii_lowercase();
    let length = head.lines().find_map(|l| l.strip_prefix("content-length:")).and_then(|v| v.trim().parse::<usize>().ok());
    let chunked = head.lines().any(|l| l.starts_with("transfer-encoding:") && l.contains("chunked"));
    loop {
        let body = &buf[end..];
        let complete = match length {
            Some(n) => body.len() >= n,
            None if chunked => body.ends_with(b"0\r\n\r\n"),
            None => true,
        };
        if complete {
            return Ok(buf);
        }
        let n = client.read(&mut chunk)?;
        if n == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        buf.extend_from_slice(&chunk[..n]);
    }
}

fn serve_one(mut client: TcpStream, target: u16, failing: &AtomicBool, refused: &AtomicUsize, forwarded: &AtomicUsize) -> std::io::Result<()> {
    client.set_read_timeout(Some(Duration::from_secs(60)))?;
    let request = read_request(&mut client)?;
    if failing.load(Ordering::SeqCst) {
        refused.fetch_add(1, Ordering::SeqCst);
        let body = "<Error><Code>ServiceUnavailable</Code><Message>the test proxy is failing</Message></Error>";
        let reply = format!("HTTP/1.1 503 Service Unavailable\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}", body.len());
        return client.write_all(reply.as_bytes());
    }
    let mut server = TcpStream::connect(("127.0.0.1", target))?;
    server.set_read_timeout(Some(Duration::from_secs(60)))?;
    server.write_all(&with_close(&request))?;
    let mut response = Vec::new();
    server.read_to_end(&mut response)?;
    forwarded.fetch_add(1, Ordering::SeqCst);
    client.write_all(&with_close(&response))
}

/// A listener on 127.0.0.1 that counts the connections made to it and answers each request with 404:
/// put where a client would find a cloud's instance metadata service (`AWS_METADATA_ENDPOINT`), it
/// shows whether the client looked there.
pub struct MetadataTrap {
    pub port: u16,
    pub calls: Arc<AtomicUsize>,
    down: Arc<AtomicBool>,
}

impl MetadataTrap {
    pub fn start() -> MetadataTrap {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let port = listener.local_addr().unwrap().port();
        let (calls, down): (Arc<AtomicUsize>, Arc<AtomicBool>) = Default::default();
        let (c, d) = (calls.clone(), down.clone());
        std::thread::spawn(move || {
            while !d.load(Ordering::SeqCst) {
                match listener.accept() {
                    Ok((mut s, _)) => {
                        c.fetch_add(1, Ordering::SeqCst);
                        let _ = s.set_nonblocking(false);
                        let _ = s.set_read_timeout(Some(Duration::from_secs(5)));
                        let _ = read_request(&mut s);
                        let _ = s.write_all(b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n");
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(2)),
                }
            }
        });
        MetadataTrap { port, calls, down }
    }

    pub fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    pub fn calls(&self) -> usize {
        self.calls.load(Ordering::SeqCst)
    }
}

impl Drop for MetadataTrap {
    fn drop(&mut self) {
        self.down.store(true, Ordering::SeqCst);
    }
}
