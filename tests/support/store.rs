//! A real S3 server for the object-store tests: moto (`python3 -m moto.server`, installed from PyPI by
//! scripts/install-test-deps.sh) on a free port, killed when its guard drops (also when a test fails);
//! and a TCP proxy in front of it that a test can stop, as a store that goes away mid-build.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
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
        let mut child = Command::new(super::python())
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

    /// Sets [`Moto::vars`] in this test process (hold [`ENV`] while doing so).
    pub fn set_env(&self) {
        for (k, v) in Moto::vars(&self.endpoint()) {
            std::env::set_var(k, v);
        }
    }

    /// Turns on moto's authentication from now on: every request must be signed with a key made by IAM.
    pub fn require_auth(&self) {
        let status = http(self.port, "POST", "/moto-api/reset-auth", "0");
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
