//! A real Azure Blob server for the `az://` tests: Azurite (`azurite-blob` from npm, installed pinned by
//! scripts/install-test-deps.sh) on 127.0.0.1 and a free port, in memory, killed when its guard drops (also
//! when a test fails). Clients reach it through object_store's emulator mode (`AZURE_STORAGE_USE_EMULATOR`,
//! `AZURITE_BLOB_STORAGE_URL`: the well-known development account and key), so no test can fall back to a
//! cloud endpoint or a metadata address. Tests fail (never skip) when it cannot start.

use std::io::{BufRead, BufReader, Read};
use std::net::TcpListener;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Serialises the tests that point this process's `AZURE_*` variables at their own Azurite (the `AWS_*`
/// ones have their own lock, `store::ENV`: an Azure test and an S3 test may run side by side).
pub static ENV: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// A running Azurite blob service.
pub struct Azurite {
    child: Child,
    pub port: u16,
    /// How long it took from spawn to listening.
    pub startup: Duration,
}

/// The program: `AZURITE_BLOB` if set, else `azurite-blob` on the PATH (npm's global bin).
fn program() -> String {
    std::env::var("AZURITE_BLOB").ok().filter(|v| !v.is_empty()).unwrap_or_else(|| "azurite-blob".into())
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

enum Started {
    Listening,
    Failed(String),
}

impl Azurite {
    /// Starts `azurite-blob --blobHost 127.0.0.1 --blobPort <free port> --inMemoryPersistence
    /// --disableTelemetry --skipApiVersionCheck --loose` and waits until it listens (a port taken
    /// meanwhile by someone else is retried with another one).
    pub fn start() -> Azurite {
        let mut last = String::new();
        for _ in 0..3 {
            match Azurite::try_start(free_port()) {
                Ok(a) => return a,
                Err(e) if e.contains("EADDRINUSE") => last = e,
                Err(e) => panic!(
                    "Azurite did not start: {e}\n(run scripts/install-test-deps.sh, which installs npm's azurite)"
                ),
            }
        }
        panic!("Azurite did not start (ports taken): {last}")
    }

    fn try_start(port: u16) -> Result<Azurite, String> {
        let t0 = Instant::now();
        let port_s = port.to_string();
        let mut child = Command::new(program())
            .args(["--blobHost", "127.0.0.1", "--blobPort", &port_s])
            .args(["--inMemoryPersistence", "--disableTelemetry", "--skipApiVersionCheck", "--loose"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("cannot run `{}` ({e})", program()))?;
        let (tx, rx) = mpsc::channel();
        let (out, mut err) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
        let tx2 = tx.clone();
        std::thread::spawn(move || {
            // Azurite prints one access-log line per request: keep draining so it never blocks.
            let mut sent = false;
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if !sent && line.contains("successfully listens on") {
                    let _ = tx.send(Started::Listening);
                    sent = true;
                }
            }
            let _ = tx.send(Started::Failed("its output ended".into()));
        });
        std::thread::spawn(move || {
            let mut text = String::new();
            let _ = err.read_to_string(&mut text);
            if !text.trim().is_empty() {
                let _ = tx2.send(Started::Failed(text));
            }
        });
        let mut guard = Azurite { child, port, startup: Duration::ZERO };
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(Started::Listening) => {
                guard.startup = t0.elapsed();
                Ok(guard)
            }
            Ok(Started::Failed(why)) => {
                let status = guard.child.try_wait().ok().flatten();
                Err(format!("{why} (exit status {status:?})"))
            }
            Err(_) => Err("it did not listen within 60 s".into()),
        }
    }

    /// `http://127.0.0.1:<port>`: what `AZURITE_BLOB_STORAGE_URL` and the Python peer take.
    pub fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// The environment that points a client at the Azurite behind `endpoint`: object_store's emulator
    /// mode, short retries. Every other `AZURE_*` variable must be removed ([`Azurite::apply`] does).
    pub fn vars(endpoint: &str) -> Vec<(&'static str, String)> {
        vec![
            ("AZURE_STORAGE_USE_EMULATOR", "true".into()),
            ("AZURITE_BLOB_STORAGE_URL", endpoint.to_string()),
            ("POINTREGGPT_STORE_RETRY_SECONDS", "3".into()),
        ]
    }

    /// Points `cmd` at `endpoint` only: drops the `AZURE_*` variables it inherited (an account name or a
    /// key there would leave emulator mode or change the account), then sets [`Azurite::vars`].
    pub fn apply<'a>(cmd: &'a mut Command, endpoint: &str) -> &'a mut Command {
        for (k, _) in std::env::vars_os() {
            if k.to_string_lossy().starts_with("AZURE_") {
                cmd.env_remove(&k);
            }
        }
        cmd.envs(Azurite::vars(endpoint))
    }

    /// The same for this test process (hold [`ENV`] while doing so).
    pub fn set_env(&self) {
        for (k, _) in std::env::vars_os() {
            if k.to_string_lossy().starts_with("AZURE_") {
                std::env::remove_var(&k);
            }
        }
        for (k, v) in Azurite::vars(&self.endpoint()) {
            std::env::set_var(k, v);
        }
    }
}

impl Drop for Azurite {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
