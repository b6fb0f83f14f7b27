//! Reading OpenCV FileStorage XML (`cv::FileStorage`), the format third-party structured-light
//! tools (OpenCV procam calibration, SLStudio) store calibrations in.

use std::collections::BTreeMap;
use std::path::Path;

use crate::{Error, Result};

/// A numeric node: a matrix (rows × cols, row-major) or a scalar (1 × 1).
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Values, row-major.
    pub data: Vec<f64>,
}

/// The top-level numeric nodes of a FileStorage XML file, by name.
#[derive(Clone, Debug)]
pub struct FileStorage {
    path: String,
    nodes: BTreeMap<String, Node>,
}

impl FileStorage {
    /// Parse `path`. Only top-level matrices (`type_id="opencv-matrix"`) and numbers are kept.
    pub fn load(path: &Path) -> Result<FileStorage> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let bad = |m: String| Error::Format {
            path: path.to_path_buf(),
            message: m,
        };
        let body = text
            .split_once("<opencv_storage>")
            .map(|x| x.1)
            .ok_or_else(|| bad("no <opencv_storage> root".into()))?;
        let body = body.split("</opencv_storage>").next().unwrap_or(body);
        let mut nodes = BTreeMap::new();
        let mut rest = body;
        while let Some(open) = rest.find('<') {
            rest = &rest[open + 1..];
            if rest.starts_with('!') || rest.starts_with('?') || rest.starts_with('/') {
                continue;
            }
            let end = rest
                .find('>')
                .ok_or_else(|| bad("unterminated tag".into()))?;
            let tag = &rest[..end];
            let name = tag.split_whitespace().next().unwrap_or("").to_string();
            let close = format!("</{name}>");
            let content_end = rest
                .find(&close)
                .ok_or_else(|| bad(format!("no closing tag for <{name}>")))?;
            let content = &rest[end + 1..content_end];
            rest = &rest[content_end + close.len()..];
            if tag.contains("opencv-matrix") {
                let field = |f: &str| -> Result<&str> {
                    let s = content
                        .split_once(&format!("<{f}>"))
                        .map(|x| x.1)
                        .ok_or_else(|| bad(format!("<{name}> has no <{f}>")))?;
                    Ok(s.split_once(&format!("</{f}>")).map(|x| x.0).unwrap_or(s))
                };
                let rows: usize = field("rows")?
                    .trim()
                    .parse()
                    .map_err(|_| bad(format!("<{name}>: bad rows")))?;
                let cols: usize = field("cols")?
                    .trim()
                    .parse()
                    .map_err(|_| bad(format!("<{name}>: bad cols")))?;
                let data: Vec<f64> = field("data")?
                    .split_whitespace()
                    .map(|v| {
                        v.parse::<f64>()
                            .map_err(|_| bad(format!("<{name}>: bad number `{v}`")))
                    })
                    .collect::<Result<_>>()?;
                if data.len() != rows * cols {
                    return Err(bad(format!(
                        "<{name}> has {} values for {rows}x{cols}",
                        data.len()
                    )));
                }
                nodes.insert(name, Node { rows, cols, data });
            } else if let Ok(v) = content.trim().parse::<f64>() {
                nodes.insert(
                    name,
                    Node {
                        rows: 1,
                        cols: 1,
                        data: vec![v],
                    },
                );
            }
        }
        Ok(FileStorage {
            path: path.display().to_string(),
            nodes,
        })
    }

    /// The node `name`, with an error naming the file if it is absent.
    pub fn get(&self, name: &str) -> Result<&Node> {
        self.nodes
            .get(name)
            .ok_or_else(|| Error::invalid(&self.path, name, "missing"))
    }

    /// A 3×3 matrix as rows.
    pub fn mat3(&self, name: &str) -> Result<[[f64; 3]; 3]> {
        let n = self.get(name)?;
        if n.data.len() != 9 {
            return Err(Error::invalid(
                &self.path,
                name,
                format!("expected 3x3, found {}x{}", n.rows, n.cols),
            ));
        }
        let d = &n.data;
        Ok([[d[0], d[1], d[2]], [d[3], d[4], d[5]], [d[6], d[7], d[8]]])
    }

    /// A vector of exactly `N` values.
    pub fn vector<const N: usize>(&self, name: &str) -> Result<[f64; N]> {
        let n = self.get(name)?;
        n.data.as_slice().try_into().map_err(|_| {
            Error::invalid(
                &self.path,
                name,
                format!("expected {N} values, found {}", n.data.len()),
            )
        })
    }

    /// A scalar.
    pub fn scalar(&self, name: &str) -> Result<f64> {
        Ok(self.get(name)?.data[0])
    }
}
