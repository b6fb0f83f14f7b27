//! Exposure and gain in RIS units (µs, dB) mapped onto V4L2 integer controls, checked against
//! the range, step and unit the device reports.

/// `V4L2_CID_EXPOSURE_AUTO` (menu; 1 = manual).
pub const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
/// `V4L2_CID_EXPOSURE_ABSOLUTE`, in units of 100 µs.
pub const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
/// `V4L2_CID_AUTOGAIN` (boolean).
pub const CID_AUTOGAIN: u32 = 0x0098_0912;
/// `V4L2_CID_GAIN` (device units).
pub const CID_GAIN: u32 = 0x0098_0913;
/// The manual setting of `V4L2_CID_EXPOSURE_AUTO`.
pub const EXPOSURE_MANUAL: i64 = 1;

/// The range of an integer control as the device reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ControlRange {
    /// Smallest value.
    pub min: i64,
    /// Largest value.
    pub max: i64,
    /// Values are `min + k·step`.
    pub step: i64,
}

impl ControlRange {
    /// The valid value nearest `v`, or `None` when `v` lies outside the range by more than
    /// half a step.
    pub fn snap(&self, v: f64) -> Option<i64> {
        let step = self.step.max(1) as f64;
        let k = ((v - self.min as f64) / step).round();
        let snapped = self.min as f64 + k * step;
        (v.is_finite() && snapped >= self.min as f64 && snapped <= self.max as f64)
            .then_some(snapped as i64)
    }
}

/// The `V4L2_CID_EXPOSURE_ABSOLUTE` value for an exposure of `us` µs.
pub fn exposure_value(us: f64, range: &ControlRange) -> Result<i64, String> {
    range.snap(us / 100.0).ok_or_else(|| {
        format!(
            "exposure {us} µs is outside the device's {}..={} µs",
            range.min * 100,
            range.max * 100
        )
    })
}

/// The exposure in µs of a `V4L2_CID_EXPOSURE_ABSOLUTE` value.
pub fn exposure_us(value: i64) -> f64 {
    value as f64 * 100.0
}

/// The `V4L2_CID_GAIN` value for `db`. V4L2 gain has no unit: with `db_per_unit` (from the
/// camera's configuration) the value is `min + db / db_per_unit`; without it only 0 dB (the
/// minimum gain) is meaningful.
pub fn gain_value(db: f64, range: &ControlRange, db_per_unit: Option<f64>) -> Result<i64, String> {
    match db_per_unit {
        Some(k) if k.is_finite() && k > 0.0 => {
            range.snap(range.min as f64 + db / k).ok_or_else(|| {
                format!(
                    "gain {db} dB is outside the device's 0..={:.1} dB",
                    (range.max - range.min) as f64 * k
                )
            })
        }
        _ if db == 0.0 => Ok(range.min),
        _ => Err(format!(
            "gain {db} dB: this device's gain has no unit; configure its dB per unit, or use 0 dB"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EXPOSURE: ControlRange = ControlRange {
        min: 3,
        max: 2047,
        step: 1,
    };

    #[test]
    fn exposure_maps_to_hundred_microsecond_units_within_range() {
        assert_eq!(exposure_value(10_000.0, &EXPOSURE), Ok(100));
        assert_eq!(exposure_value(10_040.0, &EXPOSURE), Ok(100));
        assert_eq!(exposure_value(300.0, &EXPOSURE), Ok(3));
        assert_eq!(exposure_us(100), 10_000.0);
        let e = exposure_value(100.0, &EXPOSURE).expect_err("too short");
        assert!(e.contains("300..=204700"), "{e}");
        assert!(exposure_value(1e9, &EXPOSURE).is_err());
        assert!(exposure_value(f64::NAN, &EXPOSURE).is_err());
        // Steps are counted from the minimum.
        let coarse = ControlRange {
            min: 1,
            max: 101,
            step: 10,
        };
        assert_eq!(exposure_value(2_400.0, &coarse), Ok(21));
    }

    #[test]
    fn gain_needs_a_unit_except_for_zero() {
        let r = ControlRange {
            min: 16,
            max: 255,
            step: 1,
        };
        assert_eq!(gain_value(0.0, &r, None), Ok(16));
        assert!(gain_value(6.0, &r, None)
            .expect_err("no unit")
            .contains("no unit"));
        assert_eq!(gain_value(6.0, &r, Some(0.1)), Ok(76));
        assert!(gain_value(30.0, &r, Some(0.1)).is_err());
    }
}
