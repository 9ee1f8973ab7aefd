//! The README is a landing page whose commands run: it opens with the two commands (`make demo`,
//! `make test`, the latter the one `.ci/run` calls), stays under 150 lines, and every `sh` and `python`
//! block in it runs, in order, in a folder where `out/demo` was built the way `make demo` builds it (the
//! demo config, fewer frames). A block right after an HTML comment starting `<!-- not run` is left out
//! (cluster and bucket commands; other tests run those against local engines); `make` lines are left out
//! too (this test stands in for `make demo`).

use std::path::{Path, PathBuf};
use crate::support::{bin, command, python};

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
    let _timing = crate::support::timed();
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
    let _timing = crate::support::timed();
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
    // What they printed is what the dataset holds (counted here from its shards).
    let rows = pointreggpt::shards::dataset::Dataset::open(dir.path().join("out/demo")).unwrap().read_pairs().unwrap();
    let mut by_status: std::collections::BTreeMap<&str, usize> = std::collections::BTreeMap::new();
    for r in &rows {
        *by_status.entry(r.status.as_str()).or_default() += 1;
    }
    let ok = by_status.get("ok").copied().unwrap_or(0);
    assert!(ok > 0, "{by_status:?}");
    let shards = std::fs::read_dir(dir.path().join("out/demo/manifest")).unwrap().filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().starts_with("pairs-")).count();
    // A table row `status | count` (pretty tables of `query` and DuckDB alike).
    let cells = |line: &str| -> Vec<String> { line.split(['|', '│']).map(|c| c.trim().to_string()).filter(|c| !c.is_empty()).collect() };
    let has_row = |text: &str, status: &str, n: usize| text.lines().any(|l| { let c = cells(l); c.len() >= 2 && c[0] == status && c[1] == n.to_string() });
    let (sh, python_out) = (&ran.iter().find(|(_, l, _)| l == "sh").unwrap().2, ran.iter().filter(|(_, l, _)| l == "python").map(|(_, _, s)| s.as_str()).collect::<String>());
    for (status, n) in &by_status {
        assert!(has_row(sh, status, *n), "`pointreggpt query` printed no `{status} | {n}` row:\n{sh}");
        assert!(has_row(&python_out, status, *n), "DuckDB over the Delta table printed no `{status} | {n}` row:\n{python_out}");
    }
    assert!(sh.contains(&format!("pairs: {shards} shards intact, {} rows", rows.len())) && sh.contains("verify: ok"), "`pointreggpt verify` said otherwise:\n{sh}");
    assert!(sh.contains("delta: version"), "{sh}");
    assert!(python_out.contains(&format!("shape: ({ok}, 2)")), "Polars did not list the {ok} ok pairs:\n{python_out}");
    // The batch: 4 source clouds stacked (their lengths add up to the stacked points), 4 poses.
    let batch = python_out.lines().find(|l| l.starts_with("torch.Size")).unwrap();
    let numbers: Vec<usize> = batch.split(|c: char| !c.is_ascii_digit()).filter(|s| !s.is_empty()).map(|s| s.parse().unwrap()).collect();
    // torch.Size([N, 3]) [a, b, c, d] torch.Size([M, 3]) torch.Size([4, 4, 4])
    assert_eq!(numbers.len(), 2 + 4 + 2 + 3, "{batch}");
    assert_eq!(numbers[0], numbers[2..6].iter().sum::<usize>(), "{batch}: the stacked source points are the four clouds'");
    assert_eq!((numbers[1], numbers[7], &numbers[8..]), (3, 3, &[4, 4, 4][..]), "{batch}");
}

/// What counts as a figure in the README's "What is measured" section, and the text units a figure's
/// link must share with it. The rule, kept simple on purpose:
/// - The section runs from `## What is measured` to the next `## ` heading. Fenced code blocks, HTML
///   comments and headings are left out; inline code (`…`) and link targets (`](…)`) are removed before
///   figures are looked for (so `--noise 0.005` and `2026-12-06` in a path are not figures).
/// - A **number** is a run of digits, with `.` or `,` allowed between digits, touching no letter, digit or
///   `_` on either side (so `3DMatch`, `v1`, `fr3`, `50th` hold none). It is a **figure** if it has a
///   decimal point, or a sign right before it (`+`, `−`, `±`, or `-` after a space or bracket), or is
///   followed (after at most one space) by `%` or a unit: points, mIoU, pairs/s, min, ms, s, h, GB, MB, KB,
///   cm, mm, m. A plain count (`64 real pairs`, `3 seeds`, frame ranges `0–149`) is not a figure.
/// - A **unit** is a whole bullet (a `- ` line with its indented continuation lines), or one sentence of
///   any other paragraph (split at `.`, `!` or `?` followed by whitespace).
/// - Every unit that holds a figure must hold a Markdown link into the lab notebook (`](docs/lab/…)`),
///   and every such link must name a file of the checkout.
fn figures(text: &str) -> Vec<String> {
    // Drop inline code and link targets.
    let mut plain = String::new();
    let mut rest = text;
    loop {
        let code = rest.find('`');
        let target = rest.find("](");
        // Keep the text before the backtick, or up to the link text's `]`; skip the opening `` ` `` or `(`.
        let (at, close) = match (code, target) {
            (Some(c), t) if t.is_none_or(|t| c < t) => (c, "`"),
            (_, Some(t)) => (t + 1, ")"),
            _ => break,
        };
        plain.push_str(&rest[..at]);
        let after = &rest[at + 1..];
        rest = after.find(close).map_or("", |e| &after[e + close.len()..]);
    }
    plain.push_str(rest);
    const UNITS: [&str; 14] =
        ["%", "points", "mIoU", "pairs/s", "min", "ms", "s", "h", "GB", "MB", "KB", "cm", "mm", "m"];
    let word = |c: char| c.is_alphanumeric() || c == '_';
    let c: Vec<char> = plain.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < c.len() {
        if !c[i].is_ascii_digit() || (i > 0 && (word(c[i - 1]) || c[i - 1] == '.' || c[i - 1] == ',')) {
            i += 1;
            continue;
        }
        let mut j = i;
        let inner = |k: usize| (c[k] == '.' || c[k] == ',') && c.get(k + 1).is_some_and(|d| d.is_ascii_digit());
        while j < c.len() && (c[j].is_ascii_digit() || inner(j)) {
            j += 1;
        }
        let number: String = c[i..j].iter().collect();
        if c.get(j).is_some_and(|&d| word(d)) {
            i = j;
            continue;
        }
        let before = if i > 0 { Some(c[i - 1]) } else { None };
        let signed = matches!(before, Some('+' | '−' | '±'))
            || (before == Some('-') && (i < 2 || c[i - 2].is_whitespace() || "([".contains(c[i - 2])));
        let after: String = c[j..].iter().take(12).collect();
        let after = after.strip_prefix(' ').unwrap_or(after.as_str());
        let unit = UNITS.iter().any(|&u| after.strip_prefix(u).is_some_and(|r| !r.starts_with(word)));
        if number.contains('.') || signed || unit {
            out.push(number);
        }
        i = j;
    }
    out
}

/// A finished unit of [`measured_units`]: a bullet whole, a paragraph sentence by sentence.
fn push_unit(current: &mut Option<(usize, String, bool)>, units: &mut Vec<(usize, String)>) {
    let Some((line, text, bullet)) = current.take() else { return };
    if bullet {
        units.push((line, text));
        return;
    }
    let b = text.as_bytes();
    let mut start = 0;
    for k in 0..b.len() {
        if matches!(b[k], b'.' | b'!' | b'?') && b.get(k + 1).is_some_and(u8::is_ascii_whitespace) {
            units.push((line, text[start..=k].to_string()));
            start = k + 1;
        }
    }
    if !text[start..].trim().is_empty() {
        units.push((line, text[start..].to_string()));
    }
}

/// The units of the README's "What is measured" section (see [`figures`]), each with its first line.
fn measured_units(markdown: &str) -> Vec<(usize, String)> {
    let mut units = Vec::new();
    let (mut inside, mut fenced) = (false, false);
    let mut current: Option<(usize, String, bool)> = None; // first line, text, whether a bullet
    for (n, line) in markdown.lines().enumerate() {
        if line.starts_with("## ") {
            push_unit(&mut current, &mut units);
            inside = line.trim() == "## What is measured";
            continue;
        }
        if !inside {
            continue;
        }
        if line.trim_start().starts_with("```") {
            push_unit(&mut current, &mut units);
            fenced = !fenced;
            continue;
        }
        if fenced || line.trim_start().starts_with("<!--") || line.trim().is_empty() {
            push_unit(&mut current, &mut units);
            continue;
        }
        let bullet = line.starts_with("- ") || line.starts_with("* ");
        if let (false, Some((_, text, _))) = (bullet, current.as_mut()) {
            text.push(' ');
            text.push_str(line.trim());
        } else {
            push_unit(&mut current, &mut units);
            current = Some((n + 1, line.trim().to_string(), bullet));
        }
    }
    push_unit(&mut current, &mut units);
    units
}

#[test]
fn every_figure_of_what_is_measured_links_its_lab_entry() {
    let _timing = crate::support::timed();
    // The rule itself, on examples.
    let none = "64 real pairs, 3 seeds, R 0–149, 3DMatch, Kinect v1, fr3, every 50th frame, `--noise 0.005`, [x](a/2026-12-06.md)";
    assert_eq!(figures(none), Vec::<String>::new());
    let some = "**+0.3 to +5.7** points, 4.7 mIoU, 15 min, 30 %, 773 MB, [−1.42, +1.54], -2 and 160,000";
    assert_eq!(figures(some), ["0.3", "5.7", "4.7", "15", "30", "773", "1.42", "1.54", "2"]);

    let text = readme();
    let units = measured_units(&text);
    assert!(!units.is_empty(), "README.md has no `## What is measured` section with text");
    let mut missing = Vec::new();
    let mut counted = 0;
    for (line, unit) in &units {
        let found = figures(unit);
        counted += found.len();
        for part in unit.split("](docs/lab/").skip(1) {
            let target = format!("docs/lab/{}", part.split(')').next().unwrap().split('#').next().unwrap());
            assert!(Path::new(ROOT).join(&target).is_file(), "README.md line {line}: lab link {target} names no file");
        }
        if !found.is_empty() && !unit.contains("](docs/lab/") {
            missing.push(format!("line {line}: figures {found:?} without a link to docs/lab/ in: {unit}"));
        }
    }
    assert!(counted >= 10, "README.md's \"What is measured\" holds {counted} figures: is the section or the rule broken?");
    let rule = "README.md, \"What is measured\": every figure links the lab entry it comes from";
    assert!(missing.is_empty(), "{rule}\n{}", missing.join("\n"));
}
