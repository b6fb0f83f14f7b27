//! Exports of a part's characteristic values: CSV (one row per scan, one column per
//! characteristic) and AQDEF, the Q-DAS ASCII transfer format (`.dfq`) that automotive SPC
//! software imports. The AQDEF file has the description part (K0100 characteristics, K1001
//! part, per characteristic K2001 number, K2002 description, K2101 nominal, K2110/K2111 lower
//! and upper specification limits, K2142 unit) and the values in the K-field form: per scan
//! and characteristic K0001 value, K0002 attribute (0: valid), K0004 date/time
//! (`dd.mm.yyyy/hh:mm:ss`), K0012 measuring equipment (the cell), K0014 part ident (serial)
//! and K0008 operator when known. Values are written with the shortest text that reads back
//! as the same double, so an importer sees exactly the report's numbers.

use std::fmt::Write as _;

use crate::characteristic::Characteristic;
use crate::history::ScanRecord;

/// One scan's row: its record and a value per characteristic column (`None`: not measured).
pub type Row = (ScanRecord, Vec<Option<f64>>);

/// An export: the part, its characteristic columns and its rows as the file's text.
pub type Render = fn(&str, &[Characteristic], &[Row]) -> String;

/// A field of AQDEF text: no line breaks, at most 255 characters (the format's longest
/// text field).
fn field(text: &str) -> String {
    text.chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .take(255)
        .collect()
}

/// `2026-11-22T08:49:21.028Z` as AQDEF's `22.11.2026/08:49:21`.
fn aqdef_time(iso: &str) -> String {
    let b = iso.as_bytes();
    if b.len() >= 19 && b[4] == b'-' && b[10] == b'T' {
        format!(
            "{}.{}.{}/{}",
            &iso[8..10],
            &iso[5..7],
            &iso[0..4],
            &iso[11..19]
        )
    } else {
        field(iso)
    }
}

/// The AQDEF (`.dfq`) text of `part`'s `columns` over `rows` (oldest first).
pub fn aqdef(part: &str, columns: &[Characteristic], rows: &[Row]) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "K0100 {}", columns.len());
    let _ = writeln!(o, "K1001 {}", field(part));
    let _ = writeln!(o, "K1002 {}", field(&format!("{part} (RIS inspection)")));
    for (i, c) in columns.iter().enumerate() {
        let k = i + 1;
        let _ = writeln!(o, "K2001/{k} {}", field(&c.name));
        let _ = writeln!(o, "K2002/{k} {}", field(&c.name));
        let _ = writeln!(o, "K2101/{k} 0");
        if let Some(l) = c.lower {
            let _ = writeln!(o, "K2110/{k} {l}");
        }
        if let Some(u) = c.upper {
            let _ = writeln!(o, "K2111/{k} {u}");
        }
        let _ = writeln!(o, "K2142/{k} {}", field(c.unit));
    }
    for (scan, values) in rows {
        for (i, v) in values.iter().enumerate() {
            let Some(v) = v else { continue };
            let k = i + 1;
            let _ = writeln!(o, "K0001/{k} {v}");
            let _ = writeln!(o, "K0002/{k} 0");
            let _ = writeln!(o, "K0004/{k} {}", aqdef_time(&scan.time));
            let _ = writeln!(o, "K0012/{k} {}", field(&scan.cell));
            if let Some(s) = &scan.serial {
                let _ = writeln!(o, "K0014/{k} {}", field(s));
            }
            if let Some(op) = &scan.operator {
                let _ = writeln!(o, "K0008/{k} {}", field(op));
            }
        }
    }
    o
}

/// A CSV field, quoted when it must be (RFC 4180); a leading `=`, `+`, `-` or `@` of text is
/// prefixed with `'` so a spreadsheet does not run it as a formula.
fn csv_field(text: &str) -> String {
    let text = if text.starts_with(['=', '+', '-', '@']) {
        format!("'{text}")
    } else {
        text.to_string()
    };
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text
    }
}

/// The CSV text of `columns` over `rows`: cell, scan, time, part, serial, tag, verdict, then
/// one column per characteristic (name and unit in the header).
pub fn csv(part: &str, columns: &[Characteristic], rows: &[Row]) -> String {
    let mut o = String::from("cell,scan_id,time,part,serial,tag,verdict");
    for c in columns {
        o.push(',');
        let name = if c.unit.is_empty() {
            c.name.clone()
        } else {
            format!("{} [{}]", c.name, c.unit)
        };
        o.push_str(&csv_field(&name));
    }
    o.push_str("\r\n");
    for (scan, values) in rows {
        let text = [
            scan.cell.as_str(),
            scan.scan_id.as_str(),
            scan.time.as_str(),
            part,
            scan.serial.as_deref().unwrap_or(""),
            scan.tag.as_deref().unwrap_or(""),
            scan.verdict.as_deref().unwrap_or(""),
        ];
        o.push_str(&text.map(csv_field).join(","));
        for v in values {
            o.push(',');
            if let Some(v) = v {
                let _ = write!(o, "{v}");
            }
        }
        o.push_str("\r\n");
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aqdef_values_read_back_exactly() {
        let columns = vec![
            Characteristic {
                name: "mean".into(),
                value: 0.0,
                lower: Some(-0.5),
                upper: Some(0.5),
                unit: "mm",
            },
            Characteristic {
                name: "rms".into(),
                value: 0.0,
                lower: None,
                upper: Some(0.5),
                unit: "mm",
            },
        ];
        let scan = ScanRecord {
            cell: "c1".into(),
            scan_id: "20261122T084921.028Z-0".into(),
            serial: Some("SN\n1".into()),
            time: "2026-11-22T08:49:21.028Z".into(),
            ..ScanRecord::default()
        };
        let v = 0.1 + 0.2;
        let text = aqdef("panel", &columns, &[(scan, vec![Some(v), None])]);
        assert!(
            text.contains("K0100 2\n") && text.contains("K2110/1 -0.5\n"),
            "{text}"
        );
        assert!(!text.contains("K2110/2"), "{text}");
        let value: f64 = text
            .lines()
            .find_map(|l| l.strip_prefix("K0001/1 "))
            .expect("value")
            .parse()
            .expect("number");
        assert_eq!(value, v);
        assert!(text.contains("K0004/1 22.11.2026/08:49:21\n"), "{text}");
        assert!(text.contains("K0014/1 SN 1\n"), "{text}");
        assert!(!text.contains("K0001/2"), "{text}");
    }

    #[test]
    fn csv_quotes_and_defuses_text() {
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"x\""), "\"say \"\"x\"\"\"");
        assert_eq!(csv_field("=cmd()"), "'=cmd()");
        assert_eq!(csv_field("plain"), "plain");
    }
}
