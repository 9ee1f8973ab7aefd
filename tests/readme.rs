//! The README is a landing page whose commands run: it opens with the two commands (`make demo`,
//! `make test`, the latter the one `.ci/run` calls), stays under 150 lines, and every `sh` and `python`
//! block in it runs, in order, in a folder where `out/demo` was built the way `make demo` builds it (the
//! demo config, fewer frames). A block right after an HTML comment starting `<!-- not run` is left out
//! (cluster and bucket commands; other tests run those against local engines); `make` lines are left out
//! too (this test stands in for `make demo`).

mod support;

use std::path::{Path, PathBuf};
use support::{bin, command, python};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

struct Block {
    lang: String,
    line: usize,
    text: String,
    skipped: bool,
}

/// The fenced blocks of a Markdown text, with their language, first line and whether a `<!-- not run`
/// comment right before them leaves them out.
fn blocks(markdown: &str) -> Vec<Block> {
    let mut out = Vec::new();
    let mut open: Option<Block> = None;
    let mut previous = "";
    for (i, line) in markdown.lines().enumerate() {
        if let Some(block) = open.as_mut() {
            if line.trim_start().starts_with("```") {
                out.push(open.take().unwrap());
            } else {
                block.text.push_str(line);
                block.text.push('\n');
            }
        } else if let Some(lang) = line.trim_start().strip_prefix("```") {
            open = Some(Block {
                lang: lang.trim().to_string(),
                line: i + 1,
                text: String::new(),
                skipped: previous.trim_start().starts_with("<!-- not run"),
            });
        }
        if !line.trim().is_empty() {
            previous = line;
        }
    }
    assert!(open.is_none(), "README.md: an unclosed code block");
    out
}

fn readme() -> String {
    std::fs::read_to_string(Path::new(ROOT).join("README.md")).expect("README.md")
}

#[test]
fn the_readme_opens_with_the_two_commands_and_ci_runs_the_second() {
    let text = readme();
    let lines = text.lines().count();
    assert!(lines < 150, "README.md has {lines} lines; the landing page stays under 150 (details go to docs/)");
    let first = blocks(&text).into_iter().next().expect("README.md has no code block");
    let commands: Vec<&str> = first.text.lines().map(|l| l.split('#').next().unwrap().trim()).collect();
    assert_eq!(commands, ["make demo", "make test"], "README.md's first block (line {})", first.line);
    let ci = std::fs::read_to_string(Path::new(ROOT).join(".ci/run")).expect(".ci/run");
    assert!(ci.lines().any(|l| l.trim() == "make test"), ".ci/run does not call `make test`:\n{ci}");
    // Every relative link of the README points at a file of the checkout.
    for (i, line) in text.lines().enumerate() {
        for part in line.split("](").skip(1) {
            let target = part.split(')').next().unwrap().split('#').next().unwrap();
            if target.is_empty() || target.contains("://") {
                continue;
            }
            assert!(Path::new(ROOT).join(target).exists(), "README.md line {}: link to {target}, which does not exist", i + 1);
        }
    }
}

/// `make demo`'s build, smaller: the demo config with 2 scenes of 60 frames (24 pairs).
fn build_demo(dir: &Path) {
    for link in ["pipelines", "models"] {
        std::os::unix::fs::symlink(Path::new(ROOT).join(link), dir.join(link)).unwrap();
    }
    let o = bin()
        .current_dir(dir)
        .args(["build", "pipelines/demo.toml", "--out", "out/demo", "--no-progress"])
        .args(["--set", "source.scenes=2", "--set", "source.synthetic.frames=60"])
        .output()
        .unwrap();
    assert!(o.status.success(), "the demo build failed:\n{}", String::from_utf8_lossy(&o.stderr));
}

/// The `.ply` files under `dir`, at any depth.
fn ply_files(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    entries
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .map(|p| if p.is_dir() { ply_files(&p) } else { usize::from(p.extension().is_some_and(|x| x == "ply")) })
        .sum()
}

#[test]
fn every_shell_and_python_block_of_the_readme_runs() {
    let dir = tempfile::tempdir().unwrap();
    build_demo(dir.path());
    let bin_dir: PathBuf = Path::new(env!("CARGO_BIN_EXE_pointreggpt")).parent().unwrap().to_path_buf();
    let path = format!("{}:{}", bin_dir.display(), std::env::var("PATH").unwrap_or_default());
    let mut ran = Vec::new();
    for block in blocks(&readme()) {
        if block.skipped || !(block.lang == "sh" || block.lang == "python") {
            continue;
        }
        let o = if block.lang == "sh" {
            let script: String = block
                .text
                .lines()
                .filter(|l| !l.trim_start().starts_with("make "))
                .map(|l| format!("{l}\n"))
                .collect();
            if script.trim().is_empty() {
                continue;
            }
            command("bash").current_dir(dir.path()).env("PATH", &path).args(["-euo", "pipefail", "-c", &script]).output()
        } else {
            command(python()).current_dir(dir.path()).env("PATH", &path).args(["-c", &block.text]).output()
        }
        .unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
        assert!(
            o.status.success(),
            "README.md block at line {} ({}) failed:\n{}\n{stdout}\n{}",
            block.line,
            block.lang,
            block.text,
            String::from_utf8_lossy(&o.stderr)
        );
        ran.push((block.line, block.lang, stdout));
    }
    // The blocks did what they say, not only exit 0: the query saw the pairs, the export wrote three
    // clouds' files, Python read the batch and the Delta table.
    let all: String = ran.iter().map(|(_, _, s)| s.as_str()).collect();
    assert!(ran.iter().filter(|(_, l, _)| l == "sh").count() >= 1 && ran.iter().filter(|(_, l, _)| l == "python").count() >= 2, "blocks run: {:?}", ran.iter().map(|(l, g, _)| (l, g)).collect::<Vec<_>>());
    assert!(all.contains("ok"), "no `ok` pairs in the README commands' output:\n{all}");
    let plys = ply_files(&dir.path().join("out/demo-ply"));
    assert!(plys >= 3, "export --format ply --limit 3 wrote {plys} .ply files");
    assert!(all.contains("torch.Size"), "the training-loop block printed no batch:\n{all}");
}
