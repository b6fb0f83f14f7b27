//! ROS 2 clouds over Zenoh, the way `rmw_zenoh` puts them on the wire, so ROS 2 nodes on the
//! same Zenoh network (RViz, a robot's planner) receive the cell's clouds with no bridge:
//!
//! - data key `<domain>/<topic without its leading slash>/sensor_msgs::msg::dds_::PointCloud2_/<RIHS01 hash>`,
//!   payload the CDR message ([`ris_core::cloud::pointcloud2`]);
//! - attachment: sequence number (int64), source timestamp (int64, ns since the epoch) and the
//!   publisher's 16-byte gid, in Zenoh's serialisation (little-endian integers; the gid with its
//!   length, 16, as one LEB128 byte in front);
//! - liveliness tokens for the node (`NN`) and each publisher (`MP`) under
//!   `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/...`, so `ros2 topic list` shows them.
//!
//! Topics are `<namespace>/<cell>/<sensor>/points` per sensor (the sensor's frame) and
//! `<namespace>/<cell>/merged/points` (the cell frame), with QoS reliable, volatile, keep last 10.

use std::sync::atomic::{AtomicI64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, Result};
use ris_core::cloud::pointcloud2::{Header, DDS_TYPE_NAME, TYPE_HASH};
use ris_core::cloud::PointCloud;
use zenoh::liveliness::LivelinessToken;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};

use crate::config::CellConfig;

/// The admin space of `rmw_zenoh`'s liveliness tokens.
const ADMIN_SPACE: &str = "@ros2_lv";
/// The publishers' QoS as `rmw_zenoh` writes it in a token, each field empty where it equals
/// rmw_zenoh's default (reliable, transient local, keep last 42): durability volatile (2),
/// depth 10, the rest default.
const QOS: &str = ":2:,10:,:,:,,";

/// One cloud's ROS 2 publisher.
#[derive(Debug)]
pub struct Topic {
    /// The cloud it carries: a sensor's name or `merged`.
    pub cloud: String,
    /// The fully qualified ROS 2 topic name.
    pub name: String,
    /// The tf frame of its points.
    pub frame_id: String,
    /// The Zenoh key its messages are put on.
    pub key: String,
    /// Its liveliness token's key.
    pub token: String,
    gid: [u8; 16],
    sequence: AtomicI64,
}

/// The publishers of a cell with `[ros2] enable = true`, with their liveliness tokens.
pub struct Bridge {
    /// One topic per sensor, then the merged cloud.
    pub topics: Vec<Topic>,
    /// The node's liveliness token's key.
    pub node_token: String,
    _tokens: Vec<LivelinessToken>,
}

/// A ROS 2 name in a Zenoh key: `/` becomes `%` (an empty namespace is `%`).
fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// A 16-byte gid from the publisher's token key (two FNV-1a 64-bit hashes; `rmw_zenoh` hashes
/// the same key, with XXH3, so gids are unique per entity and stable across restarts).
fn gid(key: &str) -> [u8; 16] {
    let fnv = |seed: u64| {
        key.bytes().fold(seed, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
        })
    };
    let mut g = [0u8; 16];
    g[..8].copy_from_slice(&fnv(0xcbf2_9ce4_8422_2325).to_le_bytes());
    g[8..].copy_from_slice(&fnv(0x6c62_272e_07bb_0142).to_le_bytes());
    g
}

/// The attachment `rmw_zenoh` reads from every message.
pub fn attachment(sequence: i64, timestamp_ns: i64, gid: &[u8; 16]) -> Vec<u8> {
    let mut a = Vec::with_capacity(33);
    a.extend_from_slice(&sequence.to_le_bytes());
    a.extend_from_slice(&timestamp_ns.to_le_bytes());
    a.push(16);
    a.extend_from_slice(gid);
    a
}

/// The topics of `config` for the session `zid` (empty when `[ros2]` is off).
pub fn plan(config: &CellConfig, zid: &str) -> Vec<Topic> {
    let r = &config.ros2;
    if !r.enable {
        return Vec::new();
    }
    let ns = r.namespace.trim_end_matches('/');
    let node = format!("{ADMIN_SPACE}/{}/{zid}/0", r.domain_id,);
    let clouds = config
        .sensors
        .iter()
        .map(|s| (s.name.clone(), r.sensor_frame(&config.name, &s.name)))
        .chain(std::iter::once((
            "merged".to_string(),
            r.cell_frame(&config.name),
        )));
    clouds
        .enumerate()
        .map(|(i, (cloud, frame_id))| {
            let name = format!("{ns}/{}/{cloud}/points", config.name);
            let key = format!(
                "{}/{}/{DDS_TYPE_NAME}/{TYPE_HASH}",
                r.domain_id,
                name.trim_start_matches('/')
            );
            let token = format!(
                "{node}/{}/MP/%/{}/{}/{}/{}/{TYPE_HASH}/{QOS}",
                i + 1,
                mangle(&r.namespace),
                r.node,
                mangle(&name),
                DDS_TYPE_NAME,
            );
            Topic {
                gid: gid(&token),
                cloud,
                name,
                frame_id,
                key,
                token,
                sequence: AtomicI64::new(0),
            }
        })
        .collect()
}

/// What users of a cell with access control may follow when `[ros2]` is on: its topics' data
/// keys and the domain's liveliness tokens (both empty when off).
pub fn acl_keys(config: &CellConfig) -> (Vec<String>, Vec<String>) {
    let r = &config.ros2;
    if !r.enable {
        return (Vec::new(), Vec::new());
    }
    let ns = r.namespace.trim_matches('/');
    let prefix = if ns.is_empty() {
        format!("{}/{}", r.domain_id, config.name)
    } else {
        format!("{}/{ns}/{}", r.domain_id, config.name)
    };
    (
        vec![format!("{prefix}/**")],
        vec![format!("{ADMIN_SPACE}/{}/**", r.domain_id)],
    )
}

impl Bridge {
    /// Declare the node and its publishers on `session`; `None` when `[ros2]` is off.
    pub async fn declare(session: &Session, config: &CellConfig) -> Result<Option<Bridge>> {
        if !config.ros2.enable {
            return Ok(None);
        }
        let zid = session.zid().to_string();
        let topics = plan(config, &zid);
        let r = &config.ros2;
        let node_token = format!(
            "{ADMIN_SPACE}/{}/{zid}/0/0/NN/%/{}/{}",
            r.domain_id,
            mangle(&r.namespace),
            r.node
        );
        let mut tokens = Vec::new();
        for key in std::iter::once(&node_token).chain(topics.iter().map(|t| &t.token)) {
            let t = session
                .liveliness()
                .declare_token(key.as_str())
                .await
                .map_err(|e| anyhow!("[ros2]: declaring the liveliness token {key}: {e}"))?;
            tokens.push(t);
        }
        for t in &topics {
            tracing::info!(topic = %t.name, frame = %t.frame_id, key = %t.key, "ROS 2 publisher");
        }
        Ok(Some(Bridge {
            topics,
            node_token,
            _tokens: tokens,
        }))
    }

    /// Publish each of a scan's clouds (name, PLY bytes) on its topic, stamped `stamp`. A cloud
    /// that fails is logged and the others still go out.
    pub fn publish(
        &self,
        session: &Session,
        clouds: &[(String, std::sync::Arc<Vec<u8>>)],
        stamp: SystemTime,
    ) {
        let since = stamp.duration_since(UNIX_EPOCH).unwrap_or_default();
        let ns = i64::try_from(since.as_nanos()).unwrap_or(i64::MAX);
        for (name, ply) in clouds {
            let Some(topic) = self.topics.iter().find(|t| &t.cloud == name) else {
                continue;
            };
            let cloud = match PointCloud::from_ply(ply, std::path::Path::new(name)) {
                Ok(c) => c,
                Err(e) => {
                    tracing::warn!(topic = %topic.name, error = %e, "ROS 2 cloud not published");
                    continue;
                }
            };
            let header = Header {
                sec: i32::try_from(since.as_secs()).unwrap_or(i32::MAX),
                nanosec: since.subsec_nanos(),
                frame_id: topic.frame_id.clone(),
            };
            let bytes = cloud.to_pointcloud2_cdr(&header);
            let seq = topic.sequence.fetch_add(1, Ordering::Relaxed) + 1;
            if let Err(e) = session
                .put(&topic.key, bytes)
                .attachment(attachment(seq, ns, &topic.gid))
                .congestion_control(CongestionControl::Block)
                .wait()
            {
                tracing::warn!(topic = %topic.name, error = %e, "ROS 2 publication failed");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn attachment_layout() {
        let a = attachment(3, -2, &[7; 16]);
        assert_eq!(a.len(), 33);
        assert_eq!(&a[..8], &3i64.to_le_bytes());
        assert_eq!(&a[8..16], &(-2i64).to_le_bytes());
        assert_eq!(a[16], 16);
        assert_eq!(&a[17..], &[7; 16]);
    }

    #[test]
    fn keys_follow_rmw_zenoh() {
        let mut c = CellConfig::parse(
            crate::config::MOCK_CELL,
            std::path::Path::new("../config"),
            "mock",
        )
        .expect("mock cell");
        assert!(plan(&c, "abc").is_empty());
        c.ros2.enable = true;
        let t = plan(&c, "abc");
        assert_eq!(t.len(), 5);
        assert_eq!(t[0].name, "/ris/mock/s1/points");
        assert_eq!(
            t[0].key,
            format!("0/ris/mock/s1/points/sensor_msgs::msg::dds_::PointCloud2_/{TYPE_HASH}")
        );
        assert_eq!(
            t[4].token,
            format!("@ros2_lv/0/abc/0/5/MP/%/%ris/risd/%ris%mock%merged%points/sensor_msgs::msg::dds_::PointCloud2_/{TYPE_HASH}/:2:,10:,:,:,,")
        );
        assert_eq!(
            (t[0].frame_id.as_str(), t[4].frame_id.as_str()),
            ("mock_s1", "mock")
        );
        assert_ne!(t[0].gid, t[1].gid);
    }
}
