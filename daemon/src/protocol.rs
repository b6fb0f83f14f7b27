//! The Zenoh protocol of a cell (SPEC §12), shared by risd and `ris scan`: key expressions and
//! the scan request with its parser. A request is a JSON object on the exact scan key; the
//! parser bounds what it echoes, so a hostile payload cannot become a huge reply or log line.

use serde::Deserialize;

/// Longest tag a request may carry, characters.
pub const MAX_TAG: usize = 256;
/// Longest piece of a request echoed in a reply or a log line, characters.
pub const MAX_ECHO: usize = 64;
/// Largest request body, bytes.
pub const MAX_REQUEST: usize = 64 * 1024;

/// `ris/<cell>/scan`.
pub fn scan_key(cell: &str) -> String {
    format!("ris/{cell}/scan")
}

/// `ris/<cell>/health`.
pub fn health_key(cell: &str) -> String {
    format!("ris/{cell}/health")
}

/// `ris/<cell>/scans/<id>/state`.
pub fn state_key(cell: &str, scan_id: &str) -> String {
    format!("ris/{cell}/scans/{scan_id}/state")
}

/// A scan request (`ris/<cell>/scan` payload: a JSON object, every field optional).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanRequest {
    /// `gray` (default); `adaptive` and `single-shot` are refused by this build.
    #[serde(default)]
    pub mode: Option<String>,
    /// Sensors to scan (default all).
    #[serde(default)]
    pub sensors: Option<Vec<String>>,
    /// Inspect the merged cloud (default: when the cell defines exactly one part, or `part`
    /// names one).
    #[serde(default)]
    pub inspect: Option<bool>,
    /// Part id (required to inspect when the cell defines several).
    #[serde(default)]
    pub part: Option<String>,
    /// Free text stored with the scan (`scan.json`), at most [`MAX_TAG`] characters.
    #[serde(default)]
    pub tag: Option<String>,
}

/// `text` cut to [`MAX_ECHO`] characters (with the full length said) for replies and logs.
pub fn echo(text: &str) -> String {
    let n = text.chars().count();
    if n <= MAX_ECHO {
        format!("{text:?}")
    } else {
        let head: String = text.chars().take(MAX_ECHO).collect();
        format!("{head:?}… ({n} characters)")
    }
}

impl ScanRequest {
    /// Parse a request body: a JSON object (`{}` for every default) of at most
    /// [`MAX_REQUEST`] bytes; arrays, scalars, an empty body and unknown fields are refused.
    pub fn parse(body: &[u8]) -> Result<ScanRequest, String> {
        if body.len() > MAX_REQUEST {
            return Err(format!(
                "the request has {} bytes; at most {MAX_REQUEST} are accepted",
                body.len()
            ));
        }
        let value: serde_json::Value = serde_json::from_slice(body).map_err(|e| {
            format!(
                "malformed request: not JSON ({}); send a JSON object such as {{}}",
                e.classify_name()
            )
        })?;
        if !value.is_object() {
            return Err("malformed request: the body must be a JSON object such as {} or {\"sensors\": [\"s1\"]}".into());
        }
        let req: ScanRequest = serde_json::from_value(value).map_err(|e| {
            let text = e.to_string();
            let cut: String = text.chars().take(200).collect();
            format!("malformed request: {cut}")
        })?;
        if let Some(tag) = &req.tag {
            let n = tag.chars().count();
            if n > MAX_TAG {
                return Err(format!("`tag` has {n} characters; at most {MAX_TAG}"));
            }
        }
        Ok(req)
    }
}

/// serde_json's error category as a word.
trait Classify {
    fn classify_name(&self) -> &'static str;
}

impl Classify for serde_json::Error {
    fn classify_name(&self) -> &'static str {
        match self.classify() {
            serde_json::error::Category::Io => "unreadable",
            serde_json::error::Category::Syntax => "syntax error",
            serde_json::error::Category::Data => "wrong data",
            serde_json::error::Category::Eof => "ends early",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_json_objects_are_requests() {
        assert!(ScanRequest::parse(b"{}").is_ok());
        assert!(ScanRequest::parse(br#"{"sensors": ["s1"], "tag": "x"}"#).is_ok());
        for bad in [
            &b""[..],
            b"[]",
            b"[\"gray\"]",
            b"null",
            b"3",
            b"\"gray\"",
            b"{",
            b"{\"x\": 1}",
        ] {
            assert!(
                ScanRequest::parse(bad).is_err(),
                "{:?}",
                String::from_utf8_lossy(bad)
            );
        }
        let long = format!(r#"{{"tag": "{}"}}"#, "t".repeat(MAX_TAG + 1));
        assert!(ScanRequest::parse(long.as_bytes())
            .expect_err("refused")
            .contains("at most"));
        let huge_field = format!(r#"{{"{}": 1}}"#, "f".repeat(100_000));
        assert!(
            ScanRequest::parse(huge_field.as_bytes())
                .expect_err("refused")
                .len()
                < 400
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { failure_persistence: None, ..Default::default() })]

        /// Any bytes: a request or a bounded error, never a panic.
        #[test]
        fn any_body_gives_a_request_or_a_bounded_error(body in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..512)) {
            if let Err(e) = ScanRequest::parse(&body) {
                proptest::prop_assert!(e.len() < 400, "{}", e);
            }
        }

        /// JSON-shaped bodies with arbitrary field names and values.
        #[test]
        fn json_bodies_are_objects_or_refused(key in "[a-z_]{0,12}", value in "[ -~]{0,40}", array in proptest::prelude::any::<bool>()) {
            let body = if array {
                format!("[{value:?}]")
            } else {
                format!("{{{key:?}: {value:?}}}")
            };
            match ScanRequest::parse(body.as_bytes()) {
                Ok(r) => proptest::prop_assert!(!array && r.tag.as_deref().is_none_or(|t| t.chars().count() <= MAX_TAG)),
                Err(e) => proptest::prop_assert!(e.len() < 400, "{}", e),
            }
        }
    }

    #[test]
    fn echoes_are_bounded() {
        assert_eq!(echo("s1"), "\"s1\"");
        let e = echo(&"x".repeat(1_000_000));
        assert!(e.len() < 100 && e.contains("1000000 characters"), "{e}");
    }
}
