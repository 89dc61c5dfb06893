//! The documentation as a reader meets it: the README stays a front door (short, with the two
//! set-up commands `.ci/run` relies on), and every relative link in the README and the `docs/`
//! pages leads to a file and, with an anchor, to a heading of it. The README's commands are run
//! by `tests/cli.rs`; the figures of the pages are held by the tests that compute them
//! (`common::assert_figure` names the page).

mod common;

use std::path::Path;

/// The README is a front door, not the manual.
const README_MAX_LINES: usize = 250;

/// The README's main command, as `tests/cli.rs` runs it.
const MAIN_COMMAND: &str =
    "cargo run -- replay examples/g1_example.mcap --model paper --save example.rrd";

/// The command `.ci/run` runs the tests with: its last line that runs `cargo test`, from
/// `cargo test` on (what comes before it is the CI's time limit).
fn ci_test_command() -> String {
    let ci = common::doc_page(".ci/run");
    let line = ci
        .lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .rfind(|l| l.contains("cargo test"))
        .expect(".ci/run runs `cargo test`");
    line[line.find("cargo test").unwrap()..].trim().to_owned()
}

#[test]
fn readme_is_a_front_door_with_the_two_set_up_commands() {
    let readme = common::doc_page("README.md");
    let lines = readme.lines().count();
    assert!(
        lines <= README_MAX_LINES,
        "README.md has {lines} lines (at most {README_MAX_LINES}): move the detail to docs/"
    );
    let commands: Vec<String> = common::doc_blocks("README.md", "sh")
        .into_iter()
        .flatten()
        .collect();
    let test_command = ci_test_command();
    assert_eq!(test_command, "cargo test", ".ci/run's test command");
    for command in [MAIN_COMMAND, &test_command] {
        assert!(
            commands.iter().any(|c| c == command),
            "README.md has no ```sh line `{command}`: {commands:?}"
        );
    }
}

/// The pages a reader can reach: the README and every `docs/*.md`.
fn pages() -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs");
    let mut pages = vec!["README.md".to_owned()];
    let mut docs: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".md"))
        .map(|n| format!("docs/{n}"))
        .collect();
    docs.sort();
    pages.extend(docs);
    pages
}

/// A heading's anchor as GitHub makes it: lower case, spaces to `-`, other punctuation dropped.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The relative link targets of a page (`](target)`), web addresses left out.
fn relative_links(text: &str) -> Vec<String> {
    text.match_indices("](")
        .filter_map(|(at, _)| {
            let rest = &text[at + 2..];
            let target = &rest[..rest.find(')')?];
            (!target.contains("://") && !target.is_empty()).then(|| target.to_owned())
        })
        .collect()
}

#[test]
fn documentation_links_lead_to_files_and_headings() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut checked = 0;
    for page in pages() {
        let text = common::doc_page(&page);
        let here = Path::new(&page).parent().unwrap_or(Path::new(""));
        for link in relative_links(&text) {
            let (file, fragment) = link.split_once('#').unwrap_or((&link, ""));
            let target = if file.is_empty() {
                page.clone()
            } else {
                here.join(file).to_string_lossy().into_owned()
            };
            assert!(
                root.join(&target).exists(),
                "{page}: link {link:?} leads to {target}, which does not exist"
            );
            if !fragment.is_empty() {
                let headings: Vec<String> = common::doc_page(&target)
                    .lines()
                    .filter_map(|l| l.strip_prefix('#'))
                    .map(|l| anchor(l.trim_start_matches('#')))
                    .collect();
                assert!(
                    headings.iter().any(|h| h == fragment),
                    "{page}: link {link:?}: {target} has no heading #{fragment} ({headings:?})"
                );
            }
            checked += 1;
        }
    }
    assert!(checked >= 10, "{checked} links checked");
}

/// The README's summary of results restates figures of the guides; each of its numbers is printed
/// by the guide it summarises, where a test holds it (so a figure changed there and not here, or
/// here and not there, fails).
#[test]
fn readme_summary_figures_are_the_guides() {
    let readme = common::doc_page("README.md");
    let start = readme
        .find("## What it finds")
        .expect("README has `## What it finds`");
    let section = &readme[start..];
    let section = &section[..section[3..].find("\n## ").map_or(section.len(), |e| e + 3)];
    let guides = [
        "docs/model.md",
        "docs/diagnosis-results.md",
        "docs/campaign.md",
    ]
    .map(common::doc_page);
    let numbers: Vec<&str> = section
        .split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .map(|w| w.trim_end_matches('.'))
        .filter(|w| w.contains('.') || w.len() > 1)
        .collect();
    assert!(numbers.len() >= 5, "{numbers:?}");
    for n in numbers {
        assert!(
            guides.iter().any(|g| g
                .split(|c: char| !(c.is_ascii_digit() || c == '.'))
                .any(|w| w.trim_end_matches('.') == n)),
            "README's `What it finds` states {n}, which none of docs/model.md, \
             docs/diagnosis-results.md and docs/campaign.md prints"
        );
    }
}
