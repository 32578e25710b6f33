//! The OpenIGTLink fuzz corpus (`server/fuzz/seeds/igtl`, written by
//! `server/fuzz/make_seeds.py`): every `ok-*` message parses, and every
//! `bad-<cause>-*` message is refused with that cause named.

use fissure_cli::client::bridge::igtl::codec::parse_message;
use std::path::Path;

#[test]
fn every_malformed_message_of_the_corpus_is_refused_with_its_cause() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../server/fuzz/seeds/igtl");
    let mut entries: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("a directory entry").path())
        .collect();
    entries.sort();
    let (mut ok, mut bad) = (0, 0);
    for path in &entries {
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .expect("a file name");
        let bytes = std::fs::read(path).expect("readable");
        let result = parse_message(&bytes);
        if name.starts_with("ok-") {
            assert!(result.is_ok(), "{name}: {result:?}");
            ok += 1;
        } else if let Some(rest) = name.strip_prefix("bad-") {
            let e = result.expect_err(name);
            let cause = e.kind();
            assert!(
                rest.starts_with(&format!("{cause}-")) || rest == format!("{cause}.bin"),
                "{name}: refused as {cause} ({e})"
            );
            // The message names the cause in words.
            assert!(e.to_string().len() > 10, "{name}: {e}");
            bad += 1;
        } else {
            panic!("{name}: corpus files are named ok-* or bad-<cause>-*");
        }
    }
    assert!(ok >= 10 && bad >= 25, "{ok} ok, {bad} bad");
}
