//! The Slurm template `pipelines/slurm-build.sh`, run by real Slurm: a one-node cluster (Debian's
//! slurm-wlm and munge, installed by scripts/install-test-deps.sh) that the test starts as root with all
//! its state in a temporary folder and stops at the end, also when the test fails. The job array is
//! submitted with `sbatch --array=0-3 --wait`, the template unmodified, small resources given on the sbatch
//! command line; the dataset must equal a one-process build by content hash. Then one array task is
//! cancelled (`scancel <job>_<task>`) while it is committing shards, and the resubmitted array gives the
//! same dataset. The test fails (never skips) when Slurm cannot start.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};
use crate::support::{bin, digests};

const TASKS: u64 = 4;

/// A running one-node Slurm cluster (munged, slurmctld, slurmd in the foreground), stopped on drop.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
    /// (name, process), in start order; stopped in reverse.
    daemons: Vec<(&'static str, Child)>,
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// A Slurm client command for the cluster of `conf` (and no other: the SLURM_* variables of any
/// allocation the test runs in are dropped).
fn client(conf: &Path, program: &str) -> Command {
    let mut c = Command::new(program);
    for (k, _) in std::env::vars_os() {
        if k.to_string_lossy().starts_with("SLURM_") {
            c.env_remove(&k);
        }
    }
    c.env("SLURM_CONF", conf);
    c
}

fn have(program: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {program}")])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

impl Cluster {
    fn start() -> Cluster {
        let t0 = Instant::now();
        for p in ["munged", "mungekey", "slurmctld", "slurmd", "sbatch", "scancel", "scontrol", "sinfo", "squeue"] {
            assert!(
                have(p),
                "`{p}` is not installed: as root, run `apt-get install slurm-wlm munge` (Debian's Slurm and MUNGE; \
                 scripts/install-test-deps.sh does it when run as root)"
            );
        }
        let uid = Command::new("id")
            .arg("-u")
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
            .unwrap_or_default();
        assert_eq!(uid, "0", "the Slurm test runs the daemons as root (SlurmUser=root), as CI does");
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().to_path_buf();
        // munged wants every folder above its socket to be searchable by all.
        std::fs::set_permissions(&d, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
        for sub in ["state", "spool", "job"] {
            std::fs::create_dir(d.join(sub)).unwrap();
        }
        let key = d.join("munge.key");
        let o = Command::new("mungekey").arg("--create").arg(format!("--keyfile={}", key.display())).output().unwrap();
        assert!(o.status.success(), "mungekey: {}", String::from_utf8_lossy(&o.stderr));
        let conf = d.join("slurm.conf");
        let mut cluster = Cluster { dir, conf: conf.clone(), daemons: Vec::new() };
        let socket = d.join("munge.sock");
        cluster.spawn(
            "munged",
            Command::new("munged")
                .args(["-F", "--force"])
                .arg(format!("--socket={}", socket.display()))
                .arg(format!("--key-file={}", key.display()))
                .arg(format!("--log-file={}", d.join("munged.log").display()))
                .arg(format!("--pid-file={}", d.join("munged.pid").display()))
                .arg(format!("--seed-file={}", d.join("munged.seed").display())),
        );
        cluster.wait_for("munged's socket", || socket.exists());
        let p = |name: &str| d.join(name).display().to_string();
        // Ports of our own, so that a system Slurm on the default ones is never reached.
        let ports = std::iter::repeat_with(|| (free_port(), free_port())).find(|(a, b)| a != b).unwrap();
        std::fs::write(
            &conf,
            format!(
                "ClusterName=local\nSlurmctldHost=localhost\nSlurmctldPort={ctld}\nSlurmdPort={slurmd}\n\
                 SlurmUser=root\nSlurmdUser=root\nAuthType=auth/munge\nCredType=cred/munge\nAuthInfo=socket={sock}\n\
                 StateSaveLocation={state}\nSlurmdSpoolDir={spool}\n\
                 SlurmctldPidFile={ctldpid}\nSlurmdPidFile={dpid}\nSlurmctldLogFile={ctldlog}\nSlurmdLogFile={dlog}\n\
                 ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\nJobAcctGatherType=jobacct_gather/none\n\
                 AccountingStorageType=accounting_storage/none\nSwitchType=switch/none\nMpiDefault=none\n\
                 SelectType=select/cons_tres\nSelectTypeParameters=CR_Core\nReturnToService=2\n\
                 SlurmdParameters=config_overrides\nSchedulerParameters=sched_interval=1\nMailProg=/bin/true\n\
                 NodeName=localhost NodeAddr=127.0.0.1 CPUs=32 RealMemory=65536 State=UNKNOWN\n\
                 PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP\n",
                ctld = ports.0,
                slurmd = ports.1,
                sock = socket.display(),
                state = p("state"),
                spool = p("spool"),
                ctldpid = p("slurmctld.pid"),
                dpid = p("slurmd.pid"),
                ctldlog = p("slurmctld.log"),
                dlog = p("slurmd.log"),
            ),
        )
        .unwrap();
        cluster.spawn("slurmctld", Command::new("slurmctld").args(["-D", "-c"]));
        cluster.spawn("slurmd", Command::new("slurmd").arg("-D"));
        let conf2 = conf.clone();
        cluster.wait_for("the node to be idle", move || {
            let o = client(&conf2, "sinfo").args(["-h", "-N", "-o", "%t"]).output();
            o.is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "idle")
        });
        eprintln!("Slurm cluster up in {:.1} s ({})", t0.elapsed().as_secs_f64(), cluster.dir.path().display());
        cluster
    }

    /// Starts a daemon in the foreground, its output in `<name>.out`.
    fn spawn(&mut self, name: &'static str, cmd: &mut Command) {
        let out = std::fs::File::create(self.dir.path().join(format!("{name}.out"))).unwrap();
        let child = cmd
            .env("SLURM_CONF", &self.conf)
            .stdin(Stdio::null())
            .stdout(out.try_clone().unwrap())
            .stderr(out)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e} (run scripts/install-test-deps.sh)"));
        self.daemons.push((name, child));
    }

    /// Waits up to 30 s for `ready`; fails with the daemons' logs when a daemon died or time ran out.
    fn wait_for(&mut self, what: &str, ready: impl Fn() -> bool) {
        let t0 = Instant::now();
        while !ready() {
            let dead: Vec<String> = self
                .daemons
                .iter_mut()
                .filter_map(|(n, c)| c.try_wait().ok().flatten().map(|s| format!("{n} exited ({s})")))
                .collect();
            if !dead.is_empty() || t0.elapsed() > Duration::from_secs(30) {
                panic!("Slurm did not start: waiting for {what}: {dead:?}\n{}", self.logs());
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The tail of every daemon's log, for failure messages.
    fn logs(&self) -> String {
        let mut text = String::new();
        for name in ["munged.out", "munged.log", "slurmctld.out", "slurmctld.log", "slurmd.out", "slurmd.log"] {
            let body = std::fs::read_to_string(self.dir.path().join(name)).unwrap_or_default();
            let lines: Vec<&str> = body.lines().filter(|l| !l.contains("pmix")).collect();
            text += &format!("--- {name}\n{}\n", lines[lines.len().saturating_sub(15)..].join("\n"));
        }
        text
    }

    /// A Slurm client command for this cluster.
    fn cmd(&self, program: &str) -> Command {
        client(&self.conf, program)
    }

    /// `(task id, state, exit code)` of every task of array job `job`, from `scontrol -o show job`.
    fn tasks(&self, job: &str) -> Vec<(u64, String, String)> {
        let o = self.cmd("scontrol").args(["-o", "show", "job", job]).output().unwrap();
        let field = |line: &str, key: &str| {
            line.split_whitespace().find_map(|f| f.strip_prefix(key)).unwrap_or_default().to_string()
        };
        let mut tasks: Vec<_> = String::from_utf8_lossy(&o.stdout)
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                (field(l, "ArrayTaskId=").parse().unwrap_or(u64::MAX), field(l, "JobState="), field(l, "ExitCode="))
            })
            .collect();
        tasks.sort();
        tasks
    }

    /// Waits until no task of `job` is pending or running (up to 5 minutes).
    fn wait_job(&self, job: &str) {
        let t0 = Instant::now();
        loop {
            let o = self.cmd("squeue").args(["-h", "-j", job]).output().unwrap();
            if String::from_utf8_lossy(&o.stdout).trim().is_empty() {
                return;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(300),
                "job {job} still running after 5 minutes\n{}",
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

impl Drop for Cluster {
    /// Cancels every job, waits for them to end, then stops slurmd, slurmctld and munged.
    fn drop(&mut self) {
        if let Ok(o) = self.cmd("squeue").args(["-h", "-o", "%A"]).output() {
            if !String::from_utf8_lossy(&o.stdout).trim().is_empty() {
                let _ = self.cmd("scancel").args(["--partition", "debug"]).status();
                let t0 = Instant::now();
                while t0.elapsed() < Duration::from_secs(20)
                    && self
                        .cmd("squeue")
                        .args(["-h"])
                        .output()
                        .is_ok_and(|o| !String::from_utf8_lossy(&o.stdout).trim().is_empty())
                {
                    std::thread::sleep(Duration::from_millis(200));
                }
            }
        }
        while let Some((_, mut child)) = self.daemons.pop() {
            let _ = Command::new("kill").args(["-TERM", &child.id().to_string()]).status();
            let t0 = Instant::now();
            while child.try_wait().ok().flatten().is_none() && t0.elapsed() < Duration::from_secs(10) {
                std::thread::sleep(Duration::from_millis(50));
            }
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// pipelines/demo.toml made small: 320 units at 160×120 (working size 64), two per shard: 160 shards, 40 per task.
/// (Its checkpoint path is relative to its folder, so the jobs find it from their temporary folder.)
fn demo_overrides() -> Vec<String> {
    [
        "source.scenes=2",
        "source.synthetic.frames=160",
        "select.every=1",
        "shard_size=2",
        "working.size=64",
        "source.synthetic.intrinsics.width=160",
        "source.synthetic.intrinsics.height=120",
        "source.synthetic.intrinsics.fx=146.25",
        "source.synthetic.intrinsics.fy=146.25",
        "source.synthetic.intrinsics.cx=80",
        "source.synthetic.intrinsics.cy=60",
    ]
    .iter()
    .map(|s| s.to_string())
    .flat_map(|s| ["--set".to_string(), s])
    .collect()
}
const SHARDS: u64 = 160;

fn demo() -> String {
    format!("{}/pipelines/demo.toml", env!("CARGO_MANIFEST_DIR"))
}

fn ok(o: Output) -> String {
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Committed shards of worker `task` (k mod TASKS = task) in the folder `dataset`.
fn committed_of(dataset: &Path, task: u64) -> u64 {
    let Ok(entries) = std::fs::read_dir(dataset.join("manifest")) else { return 0 };
    entries
        .filter_map(|e| {
            e.ok()?.file_name().to_str()?.strip_prefix("pairs-")?.strip_suffix(".json")?.parse::<u64>().ok()
        })
        .filter(|k| k % TASKS == task)
        .count() as u64
}

/// `sbatch [--wait] --array=0-3 --cpus-per-task=1 --mem=1G pipelines/slurm-build.sh demo.toml <out> --set …`,
/// submitted from `cwd` (where the template writes its logs/), the binary of this build through
/// POINTREGGPT_BIN (exported to the job, as sbatch does with the submitting environment).
fn sbatch(cluster: &Cluster, cwd: &Path, out: &Path, wait: bool) -> Command {
    let mut c = cluster.cmd("sbatch");
    c.current_dir(cwd).env("POINTREGGPT_BIN", env!("CARGO_BIN_EXE_pointreggpt"));
    if wait {
        c.arg("--wait");
    } else {
        c.arg("--parsable");
    }
    c.arg(format!("--array=0-{}", TASKS - 1))
        .args(["--cpus-per-task=1", "--mem=1G"])
        .arg(format!("{}/pipelines/slurm-build.sh", env!("CARGO_MANIFEST_DIR")))
        .arg(demo())
        .arg(out)
        .args(demo_overrides())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    c
}

/// Waits for `sbatch --wait` (up to 10 minutes: a job that can never run would hang it).
fn finish(mut child: Child, cluster: &Cluster) -> Output {
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > Duration::from_secs(600) {
            let _ = child.kill();
            panic!("sbatch --wait still waiting after 10 minutes\n{}", cluster.logs());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    child.wait_with_output().unwrap()
}

/// The job id that `sbatch` printed ("Submitted batch job N" or, with --parsable, "N").
fn job_id(stdout: &str) -> String {
    stdout.split_whitespace().last().unwrap_or_default().split(';').next().unwrap().to_string()
}

/// The build log the template wrote for task `task` of `job` under `cwd`.
fn task_log(cwd: &Path, job: &str, task: u64) -> String {
    let path = cwd.join(format!("logs/pointreggpt-build-{job}_{task}.out"));
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn the_slurm_template_builds_the_one_process_dataset_and_a_cancelled_task_resumes() {
    let _timing = crate::support::timed();
    let cluster = Cluster::start();
    let root = cluster.dir.path().to_path_buf();

    // The reference: one process, no scheduler.
    let reference_dir = root.join("reference");
    let t = Instant::now();
    ok(bin()
        .args(["--threads", "2", "build", &demo(), "--out", reference_dir.to_str().unwrap(), "--no-progress"])
        .args(demo_overrides())
        .output()
        .unwrap());
    let reference = digests(&reference_dir);
    assert_eq!(reference.len() as u64, SHARDS * 2);
    eprintln!("one-process build: {:.1} s", t.elapsed().as_secs_f64());

    // 1. The array, submitted as the template says, waited for.
    let cwd = root.join("job");
    let out = root.join("array");
    let t = Instant::now();
    let o = finish(sbatch(&cluster, &cwd, &out, true).spawn().unwrap(), &cluster);
    let said = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "sbatch --wait failed: {said}{}\n{}",
        String::from_utf8_lossy(&o.stderr),
        cluster.logs()
    );
    let job = job_id(&said);
    eprintln!("sbatch --array=0-3 --wait: job {job}, {:.1} s", t.elapsed().as_secs_f64());
    let tasks = cluster.tasks(&job);
    assert_eq!(
        tasks.iter().map(|t| (t.0, t.1.as_str())).collect::<Vec<_>>(),
        (0..TASKS).map(|i| (i, "COMPLETED")).collect::<Vec<_>>(),
        "{tasks:?}"
    );
    for i in 0..TASKS {
        // The template made its logs/ folder and each task built its own quarter of the shards.
        let log = task_log(&cwd, &job, i);
        let want = format!("worker {i} of {TASKS}: 0 shards already committed, {} committed now", SHARDS / TASKS);
        assert!(log.contains(&want), "task {i}: `{want}` not in:\n{log}");
        let slurm_out = std::fs::read_to_string(cwd.join(format!("slurm-pointreggpt-build-{job}_{i}.out"))).unwrap();
        assert!(slurm_out.trim().is_empty(), "task {i} wrote to Slurm's file before its log: {slurm_out}");
    }
    assert_eq!(
        digests(&out),
        reference,
        "the job array's dataset equals the one-process build, content hash for content hash"
    );

    // 2. One task cancelled while it commits shards, then the array resubmitted. A cancel that came
    // after the task had committed all its shards did not land mid-build: the setup is retried.
    let victim = 1;
    let per_task = SHARDS / TASKS;
    let mut tries = Vec::new();
    for attempt in 0..3 {
        let out = root.join(format!("cancelled-{attempt}"));
        let o = sbatch(&cluster, &cwd, &out, false).output().unwrap();
        let job = job_id(&ok(o));
        let t0 = Instant::now();
        while committed_of(&out, victim) == 0 {
            assert!(
                t0.elapsed() < Duration::from_secs(180),
                "task {victim} committed nothing in 3 minutes\n{}",
                cluster.logs()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        let at_cancel = committed_of(&out, victim);
        ok(cluster.cmd("scancel").arg(format!("{job}_{victim}")).output().unwrap());
        cluster.wait_job(&job);
        let after = committed_of(&out, victim);
        let tasks = cluster.tasks(&job);
        let state = tasks.iter().find(|t| t.0 == victim).map(|t| t.1.clone()).unwrap_or_default();
        let log = task_log(&cwd, &job, victim);
        tries.push((attempt, at_cancel, after, state.clone()));
        for t in tasks.iter().filter(|t| t.0 != victim) {
            assert_eq!(t.1, "COMPLETED", "{tasks:?}");
        }
        for (k, d) in digests(&out) {
            assert_eq!(Some(&d), reference.get(&k), "unit {k} differs after the cancel");
        }
        if !(state == "CANCELLED" && after > 0 && after < per_task) {
            eprintln!("cancel did not land mid-build: {tries:?}");
            continue;
        }
        assert!(log.contains("interrupted"), "the cancelled task's log:\n{log}");
        let cancelled = (0..TASKS).map(|i| committed_of(&out, i)).sum::<u64>();
        assert_eq!(cancelled, (TASKS - 1) * per_task + after);

        // The same submission again resumes: only the cancelled task's remaining shards are built.
        let o = finish(sbatch(&cluster, &cwd, &out, true).spawn().unwrap(), &cluster);
        let said = String::from_utf8_lossy(&o.stdout).to_string();
        assert!(o.status.success(), "resubmission failed: {said}{}", String::from_utf8_lossy(&o.stderr));
        let again = job_id(&said);
        for i in 0..TASKS {
            let log = task_log(&cwd, &again, i);
            let (done, now) = if i == victim { (after, per_task - after) } else { (per_task, 0) };
            let want = format!("worker {i} of {TASKS}: {done} shards already committed, {now} committed now");
            assert!(log.contains(&want), "task {i}: `{want}` not in:\n{log}");
        }
        assert_eq!(digests(&out), reference, "cancelled and resubmitted, the dataset equals the one-process build");
        eprintln!("cancel landed mid-build (attempt, committed at scancel, committed after, state): {tries:?}");
        return;
    }
    panic!("no scancel landed mid-build: {tries:?}");
}
