//! Clouds as ROS 2 `sensor_msgs/msg/PointCloud2` messages, serialised the way ROS 2
//! middlewares put them on the wire: plain CDR, little-endian, behind its 4-byte encapsulation
//! header. Coordinates are in metres (REP 103; RIS works in mm), fields `x y z confidence`
//! (float32). An organised cloud becomes an organised message (height × width of its camera,
//! NaN where a pixel has no point, `is_dense` false); any other cloud is one row, dense.

use super::PointCloud;

/// The ROS 2 type name of the message.
pub const TYPE_NAME: &str = "sensor_msgs/msg/PointCloud2";
/// The type's name as ROS 2 middlewares spell it on the wire.
pub const DDS_TYPE_NAME: &str = "sensor_msgs::msg::dds_::PointCloud2_";
/// The type description hash (REP 2011, RIHS01) of `sensor_msgs/msg/PointCloud2`, as every
/// ROS 2 distribution since Iron computes it; subscribers match it in key expressions.
pub const TYPE_HASH: &str =
    "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5";

/// `sensor_msgs/msg/PointField` FLOAT32.
const FLOAT32: u8 = 7;
/// Bytes per point: x, y, z, confidence.
const POINT_STEP: u32 = 16;

/// A message's header: when and in which frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    /// Seconds since the Unix epoch.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
    /// The coordinate frame of the points (a tf frame id).
    pub frame_id: String,
}

/// A CDR writer that keeps alignment relative to the end of the encapsulation header.
struct Cdr(Vec<u8>);

impl Cdr {
    fn align(&mut self, n: usize) {
        while !(self.0.len() - 4).is_multiple_of(n) {
            self.0.push(0);
        }
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }
}

impl PointCloud {
    /// The CDR bytes of this cloud as a `sensor_msgs/msg/PointCloud2` (see the module).
    pub fn to_pointcloud2_cdr(&self, header: &Header) -> Vec<u8> {
        let grid = self.organised();
        let (height, width) = match grid {
            Some([w, h]) => (h, w),
            None => (1, self.points.len() as u32),
        };
        let cells = height as usize * width as usize;
        let mut c = Cdr(Vec::with_capacity(cells * POINT_STEP as usize + 256));
        c.0.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        c.u32(header.sec as u32);
        c.u32(header.nanosec);
        c.string(&header.frame_id);
        c.u32(height);
        c.u32(width);
        let fields = ["x", "y", "z", "confidence"];
        c.u32(fields.len() as u32);
        for (i, name) in fields.iter().enumerate() {
            c.string(name);
            c.u32(4 * i as u32);
            c.u8(FLOAT32);
            c.u32(1);
        }
        c.u8(0); // is_bigendian
        c.u32(POINT_STEP);
        c.u32(POINT_STEP * width);
        c.u32((cells * POINT_STEP as usize) as u32);
        let start = c.0.len();
        let record = |p: &[f32; 3], conf: f32| {
            let mut b = [0u8; POINT_STEP as usize];
            for (k, v) in [p[0] / 1000.0, p[1] / 1000.0, p[2] / 1000.0, conf]
                .into_iter()
                .enumerate()
            {
                b[4 * k..4 * k + 4].copy_from_slice(&v.to_le_bytes());
            }
            b
        };
        let conf = |i: usize| self.confidence.get(i).copied().unwrap_or(1.0);
        match grid {
            Some(_) => {
                let empty = record(&[f32::NAN; 3], f32::NAN);
                for _ in 0..cells {
                    c.0.extend_from_slice(&empty);
                }
                for (i, (p, &px)) in self.points.iter().zip(&self.pixels).enumerate() {
                    let at = start + px as usize * POINT_STEP as usize;
                    if let Some(slot) = c.0.get_mut(at..at + POINT_STEP as usize) {
                        slot.copy_from_slice(&record(p, conf(i)));
                    }
                }
            }
            None => {
                for (i, p) in self.points.iter().enumerate() {
                    c.0.extend_from_slice(&record(p, conf(i)));
                }
            }
        }
        c.u8(u8::from(grid.is_none())); // is_dense
        c.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_of_a_small_cloud() {
        let cloud = PointCloud {
            points: vec![[1000.0, -2000.0, 500.0]],
            confidence: vec![0.25],
            ..Default::default()
        };
        let b = cloud.to_pointcloud2_cdr(&Header {
            sec: 7,
            nanosec: 9,
            frame_id: "ab".into(),
        });
        assert_eq!(&b[..4], &[0, 1, 0, 0]);
        assert_eq!(&b[4..12], &[7, 0, 0, 0, 9, 0, 0, 0]);
        // frame_id: length 3 (with its NUL), "ab\0", padded to 4 before height.
        assert_eq!(&b[12..19], &[3, 0, 0, 0, b'a', b'b', 0]);
        assert_eq!(&b[20..28], &[1, 0, 0, 0, 1, 0, 0, 0]);
        let n = b.len();
        assert_eq!(b[n - 1], 1, "is_dense");
        let x = f32::from_le_bytes([b[n - 17], b[n - 16], b[n - 15], b[n - 14]]);
        assert_eq!(x, 1.0);
    }
}
