//! The Kubernetes template `pipelines/k8s-build-job.yaml`, checked as far as this machine can without a
//! cluster: it validates against the Kubernetes schemas offline (PyPI's `kubernetes-validate`, which bundles
//! them; installed by scripts/install-test-deps.sh), strictly (unknown fields refused), and a broken copy
//! does not; its Indexed Job and the command line agree on the worker convention (`--workers` equals
//! `completions`, no `--worker`: the index comes from the JOB_COMPLETION_INDEX that Kubernetes gives each
//! pod); and the pods' command, run once per index with only JOB_COMPLETION_INDEX set, as Kubernetes would,
//! into the template's own `s3://` URL on a local S3 server with the secret's variables, builds the
//! dataset of one process, content hash for content hash.

use pointreggpt::shards::dataset::Dataset;
use serde_json::Value;
use std::collections::BTreeMap;
use std::process::{Command, Output, Stdio};
use crate::support::store::{Moto, ENV};
use crate::support::{bin, python, synthetic_config};

fn template() -> String {
    format!("{}/pipelines/k8s-build-job.yaml", env!("CARGO_MANIFEST_DIR"))
}

/// `python3 -m kubernetes_validate --strict -k <version> <file>` (the `kubernetes-validate` command).
fn validate(file: &str, version: &str) -> Output {
    let o =
        Command::new(python()).args(["-m", "kubernetes_validate", "--strict", "-k", version, file]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("No module named"), "{err}: run scripts/install-test-deps.sh (kubernetes-validate)");
    o
}

fn ok(o: Output) -> String {
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The template parsed by PyYAML (kubernetes-validate's own parser), as JSON.
fn parsed(file: &str) -> Value {
    let o = Command::new(python())
        .args(["-c", "import json, sys, yaml; print(json.dumps(yaml.safe_load(open(sys.argv[1]))))", file])
        .output()
        .unwrap();
    serde_json::from_str(&ok(o)).unwrap()
}

#[test]
fn the_kubernetes_template_validates_offline_and_a_broken_copy_does_not() {
    let _timing = crate::support::timed();
    // 1.29: the first release with backoffLimitPerIndex on by default (beta); and the newest the
    // validator bundles. Offline: the machine reaches no schema server, the schemas come with the package.
    for version in ["1.29.0", "1.37.0"] {
        let o = validate(&template(), version);
        let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(o.status.success() && text.contains("passed for resource job/pointreggpt-build"), "{version}: {text}");
    }
    // The validator is not vacuous: a misspelt field, a wrong type, and a field older releases lack.
    let dir = tempfile::tempdir().unwrap();
    let yaml = std::fs::read_to_string(template()).unwrap();
    for (from, to, version, why) in [
        (
            "restartPolicy: Never",
            "restartPolicy: Never\n      restartPolicyy: Never",
            "1.37.0",
            "'restartPolicyy' was unexpected",
        ),
        ("completions: 16", "completions: \"sixteen\"", "1.37.0", "is not of type 'integer'"),
        ("completionMode: Indexed", "completionMode: Indexed", "1.27.0", "'backoffLimitPerIndex' was unexpected"),
    ] {
        assert!(yaml.contains(from), "{from}");
        let bad = dir.path().join("bad.yaml");
        std::fs::write(&bad, yaml.replacen(from, to, 1)).unwrap();
        let o = validate(bad.to_str().unwrap(), version);
        let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        assert!(!o.status.success() && text.contains(why), "{to} ({version}): {text}");
    }
}

#[test]
fn the_kubernetes_pods_command_builds_the_one_process_dataset_with_job_completion_index() {
    let _timing = crate::support::timed();
    let job = parsed(&template());
    let spec = &job["spec"];
    assert_eq!((job["kind"].as_str(), job["apiVersion"].as_str()), (Some("Job"), Some("batch/v1")));
    assert_eq!(spec["completionMode"], "Indexed", "JOB_COMPLETION_INDEX is set only in Indexed Jobs");
    let completions = spec["completions"].as_u64().unwrap();
    assert_eq!(spec["parallelism"].as_u64(), Some(completions));
    assert!(spec["backoffLimitPerIndex"].as_u64().is_some_and(|n| n > 0), "a failed index is retried on its own");
    let pod = &spec["template"]["spec"];
    assert_eq!(pod["restartPolicy"], "Never");
    let containers = pod["containers"].as_array().unwrap();
    assert_eq!(containers.len(), 1);
    let c = &containers[0];
    let args: Vec<String> = c["command"].as_array().unwrap().iter().map(|a| a.as_str().unwrap().to_string()).collect();
    let value = |flag: &str| args.iter().position(|a| a == flag).map(|i| args[i + 1].clone());
    // The same worker convention the Slurm test proves with SLURM_ARRAY_TASK_ID / _COUNT: the index
    // from the scheduler's variable, the count from --workers (Kubernetes gives no count variable).
    assert_eq!(args[0], "pointreggpt");
    assert!(args.contains(&"build".to_string()) && args.contains(&"--no-progress".to_string()), "{args:?}");
    assert_eq!(value("--workers"), Some(completions.to_string()), "--workers must equal completions: {args:?}");
    assert!(!args.contains(&"--worker".to_string()), "the index must come from JOB_COMPLETION_INDEX: {args:?}");
    assert_eq!(
        value("--threads"),
        c["resources"]["requests"]["cpu"].as_str().map(String::from),
        "threads = the CPUs requested"
    );
    let env_names: Vec<&str> =
        c["env"].as_array().map(|e| e.iter().filter_map(|v| v["name"].as_str()).collect()).unwrap_or_default();
    assert!(
        !env_names
            .iter()
            .any(|n| n.starts_with("SLURM_") || *n == "JOB_COMPLETION_INDEX" || *n == "POINTREGGPT_WORKERS"),
        "{env_names:?}"
    );
    let out = value("--out").unwrap();
    assert!(out.starts_with("s3://"), "{out}");
    let bucket = out.trim_start_matches("s3://").split('/').next().unwrap().to_string();
    let secret = c["envFrom"][0]["secretRef"]["name"].as_str().unwrap();
    assert!(!secret.is_empty());

    // The pods, run here four indexes at a time: the container's command verbatim, but the binary of
    // this build, the config mount replaced by a small synthetic config (whose source has no
    // `source.path`, so that override is dropped), the secret's AWS_* variables pointing at moto, and
    // JOB_COMPLETION_INDEX the only worker variable.
    let _env = ENV.lock().unwrap_or_else(|e| e.into_inner());
    let moto = Moto::start();
    moto.set_env();
    moto.create_bucket(&bucket);
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("c.toml");
    let units = 2 * completions;
    std::fs::write(&config, synthetic_config(1, units as usize, 1, 1, 160, 120, 1)).unwrap();
    let config_arg = args.iter().position(|a| a == "build").unwrap() + 1;
    assert!(args[config_arg].starts_with("/config/"), "{args:?}");
    let mut pod_args: Vec<String> = Vec::new();
    let mut i = 1;
    while i < args.len() {
        if i == config_arg {
            pod_args.push(config.to_str().unwrap().into());
        } else if args[i] == "--set" && args[i + 1].starts_with("source.path=") {
            i += 1;
        } else {
            pod_args.push(args[i].clone());
        }
        i += 1;
    }
    let pod = |index: u64| {
        let mut c = bin();
        for (k, _) in std::env::vars_os() {
            let k = k.to_string_lossy().to_string();
            if k.starts_with("SLURM_")
                || k == "JOB_COMPLETION_INDEX"
                || k == "AWS_BATCH_JOB_ARRAY_INDEX"
                || k == "POINTREGGPT_WORKERS"
            {
                c.env_remove(k);
            }
        }
        c.args(&pod_args).envs(Moto::vars(&moto.endpoint())).env("JOB_COMPLETION_INDEX", index.to_string());
        c.stdout(Stdio::piped()).stderr(Stdio::piped());
        c
    };
    for batch in (0..completions).collect::<Vec<_>>().chunks(4) {
        let running: Vec<_> = batch.iter().map(|&i| (i, pod(i).spawn().unwrap())).collect();
        for (i, child) in running {
            let said = ok(child.wait_with_output().unwrap());
            let want = format!("worker {i} of {completions}: 0 shards already committed, 2 committed now");
            assert!(said.contains(&want), "index {i}: `{want}` not in {said}");
        }
    }
    let reference = dir.path().join("ref");
    ok(bin()
        .args([
            "--threads",
            "2",
            "build",
            config.to_str().unwrap(),
            "--out",
            reference.to_str().unwrap(),
            "--no-progress",
        ])
        .output()
        .unwrap());
    let digests = |d: &str| -> BTreeMap<u64, String> {
        Dataset::open(d)
            .unwrap()
            .read_pairs()
            .unwrap()
            .iter()
            .map(|r| (r.unit_index, r.content_digest().to_hex().to_string()))
            .collect()
    };
    let reference = digests(reference.to_str().unwrap());
    assert_eq!(reference.len() as u64, units);
    assert_eq!(digests(&out), reference, "{completions} pods by JOB_COMPLETION_INDEX = one process");
    // An index run again (a retried pod) finds its shards committed.
    let again = ok(pod(3).output().unwrap());
    assert!(
        again.contains(&format!("worker 3 of {completions}: 2 shards already committed, 0 committed now")),
        "{again}"
    );
}
