//! The ROS 2 messages stride reads from and writes to MCAP files, with their CDR layout and
//! their schema texts in [`super::schema`].
//!
//! Times are `builtin_interfaces/Time` (seconds and nanoseconds since the sensor's epoch);
//! images follow REP 118 (`16UC1` depth in millimetres unless the channel says otherwise,
//! `32FC1` in metres); poses are `geometry_msgs/Transform`s from `header.frame_id` to
//! `child_frame_id` (`parent_from_child`, translation in metres).

use super::cdr::{CdrError, CdrReader, CdrWriter};

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
pub struct Time {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds within the second (0 to 999,999,999).
    pub nanosec: u32,
}

impl Time {
    /// The time in seconds.
    pub fn seconds(self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }

    /// Nanoseconds since the epoch (0 for a time before it), as MCAP's `log_time`.
    pub fn nanos(self) -> u64 {
        u64::try_from(self.sec).map_or(0, |s| s * 1_000_000_000 + u64::from(self.nanosec))
    }

    /// The time of a decimal stamp such as TUM's `1341841873.273798`, digit for digit
    /// (no rounding through a float); `None` for anything else.
    pub fn parse_decimal(text: &str) -> Option<Self> {
        let (whole, frac) = text.split_once('.').unwrap_or((text, ""));
        if frac.len() > 9 || !frac.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        let sec: i32 = whole.parse().ok()?;
        if sec < 0 {
            return None;
        }
        let nanosec: u32 = format!("{frac:0<9}").parse().ok()?;
        Some(Self { sec, nanosec })
    }

    /// The time of `t_s` seconds (a stamp that exists only as a float), to the nearest
    /// microsecond: an f64 Unix time resolves about 0.24 µs, so finer digits are noise, and
    /// stamps written with six decimals (TUM's) come back digit for digit.
    pub fn from_seconds(t_s: f64) -> Self {
        let us = (t_s * 1e6).round();
        let sec = (us / 1e6).floor();
        let nanosec = ((us - sec * 1e6) as u32).min(999_999) * 1000;
        Self {
            sec: sec as i32,
            nanosec,
        }
    }

    fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            sec: r.i32("stamp.sec")?,
            nanosec: r.u32("stamp.nanosec")?,
        })
    }

    fn write(self, w: &mut CdrWriter) {
        w.i32(self.sec);
        w.u32(self.nanosec);
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Header {
    /// When the data was captured.
    pub stamp: Time,
    /// The frame the data is expressed in.
    pub frame_id: String,
}

impl Header {
    /// Reads the header at the start of a message.
    pub fn read(r: &mut CdrReader) -> Result<Self, CdrError> {
        Ok(Self {
            stamp: Time::read(r)?,
            frame_id: r.string("header.frame_id")?,
        })
    }

    fn write(&self, w: &mut CdrWriter) {
        self.stamp.write(w);
        w.string(&self.frame_id);
    }
}

/// `sensor_msgs/Image`: raw pixels, rows `step` bytes apart.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageMsg<'a> {
    /// Capture time and frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`rgb8`, `bgr8`, `mono8`, `16UC1`, `32FC1`, ...).
    pub encoding: String,
    /// 1 when multi-byte pixels are big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// The pixels.
    pub data: &'a [u8],
}

impl<'a> ImageMsg<'a> {
    /// Decodes a CDR message.
    pub fn decode(data: &'a [u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(data)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            height: r.u32("height")?,
            width: r.u32("width")?,
            encoding: r.string("encoding")?,
            is_bigendian: r.u8("is_bigendian")?,
            step: r.u32("step")?,
            data: r.bytes("data")?,
        })
    }

    /// Encodes as a CDR message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::with_capacity(self.data.len() + 64);
        self.header.write(&mut w);
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.encoding);
        w.u8(self.is_bigendian);
        w.u32(self.step);
        w.bytes(self.data);
        w.finish()
    }
}

/// `sensor_msgs/CompressedImage`: an encoded image (`png`, `jpeg`, ...).
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImageMsg<'a> {
    /// Capture time and frame.
    pub header: Header,
    /// The encoding, e.g. `png`, `jpeg`, `16UC1; compressedDepth png`.
    pub format: String,
    /// The encoded bytes.
    pub data: &'a [u8],
}

impl<'a> CompressedImageMsg<'a> {
    /// Decodes a CDR message.
    pub fn decode(data: &'a [u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(data)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            format: r.string("format")?,
            data: r.bytes("data")?,
        })
    }

    /// Encodes as a CDR message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::with_capacity(self.data.len() + 64);
        self.header.write(&mut w);
        w.string(&self.format);
        w.bytes(self.data);
        w.finish()
    }
}

/// `sensor_msgs/CameraInfo` (binning and region of interest kept as read).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfoMsg {
    /// Time and frame.
    pub header: Header,
    /// Image rows.
    pub height: u32,
    /// Image columns.
    pub width: u32,
    /// `plumb_bob`, `rational_polynomial`, `equidistant`, or empty.
    pub distortion_model: String,
    /// Distortion coefficients (`plumb_bob`: k1 k2 p1 p2 k3).
    pub d: Vec<f64>,
    /// Intrinsic matrix, row-major (`fx 0 cx; 0 fy cy; 0 0 1`).
    pub k: [f64; 9],
    /// Rectification rotation, row-major.
    pub r: [f64; 9],
    /// Projection matrix, row-major 3x4.
    pub p: [f64; 12],
    /// Binning (0 or 1: none), x then y.
    pub binning: [u32; 2],
    /// Region of interest: x_offset, y_offset, height, width, and do_rectify.
    pub roi: ([u32; 4], u8),
}

impl CameraInfoMsg {
    /// Decodes a CDR message.
    pub fn decode(data: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(data)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            height: r.u32("height")?,
            width: r.u32("width")?,
            distortion_model: r.string("distortion_model")?,
            d: r.f64_seq("d")?,
            k: r.f64_array("k")?,
            r: r.f64_array("r")?,
            p: r.f64_array("p")?,
            binning: [r.u32("binning_x")?, r.u32("binning_y")?],
            roi: (
                [
                    r.u32("roi.x_offset")?,
                    r.u32("roi.y_offset")?,
                    r.u32("roi.height")?,
                    r.u32("roi.width")?,
                ],
                r.u8("roi.do_rectify")?,
            ),
        })
    }

    /// Encodes as a CDR message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::new();
        self.header.write(&mut w);
        w.u32(self.height);
        w.u32(self.width);
        w.string(&self.distortion_model);
        w.f64_seq(&self.d);
        w.f64_array(&self.k);
        w.f64_array(&self.r);
        w.f64_array(&self.p);
        w.u32(self.binning[0]);
        w.u32(self.binning[1]);
        for v in self.roi.0 {
            w.u32(v);
        }
        w.u8(self.roi.1);
        w.finish()
    }
}

/// `sensor_msgs/Imu` (orientation and covariances kept as read).
#[derive(Debug, Clone, PartialEq)]
pub struct ImuMsg {
    /// Time and the frame the vectors are expressed in.
    pub header: Header,
    /// Orientation quaternion x, y, z, w.
    pub orientation: [f64; 4],
    /// Its covariance (row-major; -1 in the first element: no orientation).
    pub orientation_covariance: [f64; 9],
    /// Angular velocity (rad/s).
    pub angular_velocity: [f64; 3],
    /// Its covariance.
    pub angular_velocity_covariance: [f64; 9],
    /// Linear acceleration, i.e. specific force (m/s²).
    pub linear_acceleration: [f64; 3],
    /// Its covariance.
    pub linear_acceleration_covariance: [f64; 9],
}

impl ImuMsg {
    /// Decodes a CDR message.
    pub fn decode(data: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(data)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            orientation: r.f64_array("orientation")?,
            orientation_covariance: r.f64_array("orientation_covariance")?,
            angular_velocity: r.f64_array("angular_velocity")?,
            angular_velocity_covariance: r.f64_array("angular_velocity_covariance")?,
            linear_acceleration: r.f64_array("linear_acceleration")?,
            linear_acceleration_covariance: r.f64_array("linear_acceleration_covariance")?,
        })
    }

    /// Encodes as a CDR message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::new();
        self.header.write(&mut w);
        w.f64_array(&self.orientation);
        w.f64_array(&self.orientation_covariance);
        w.f64_array(&self.angular_velocity);
        w.f64_array(&self.angular_velocity_covariance);
        w.f64_array(&self.linear_acceleration);
        w.f64_array(&self.linear_acceleration_covariance);
        w.finish()
    }
}

/// `sensor_msgs/LaserScan`: ranges (m) of beams from `angle_min` in steps of
/// `angle_increment` (rad), counter-clockwise about the sensor's z axis.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserScanMsg {
    /// Time of the first beam, and the sensor frame.
    pub header: Header,
    /// Angle of the first beam (rad).
    pub angle_min: f32,
    /// Angle of the last beam (rad).
    pub angle_max: f32,
    /// Angle between beams (rad).
    pub angle_increment: f32,
    /// Time between beams (s).
    pub time_increment: f32,
    /// Time between scans (s).
    pub scan_time: f32,
    /// Shortest valid range (m).
    pub range_min: f32,
    /// Longest valid range (m).
    pub range_max: f32,
    /// Ranges (m); outside `[range_min, range_max]` or not finite: no return.
    pub ranges: Vec<f32>,
    /// Intensities (device units), possibly empty.
    pub intensities: Vec<f32>,
}

impl LaserScanMsg {
    /// Decodes a CDR message.
    pub fn decode(data: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(data)?;
        Ok(Self {
            header: Header::read(&mut r)?,
            angle_min: r.f32("angle_min")?,
            angle_max: r.f32("angle_max")?,
            angle_increment: r.f32("angle_increment")?,
            time_increment: r.f32("time_increment")?,
            scan_time: r.f32("scan_time")?,
            range_min: r.f32("range_min")?,
            range_max: r.f32("range_max")?,
            ranges: r.f32_seq("ranges")?,
            intensities: r.f32_seq("intensities")?,
        })
    }

    /// Encodes as a CDR message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::new();
        self.header.write(&mut w);
        for v in [
            self.angle_min,
            self.angle_max,
            self.angle_increment,
            self.time_increment,
            self.scan_time,
            self.range_min,
            self.range_max,
        ] {
            w.f32(v);
        }
        w.f32_seq(&self.ranges);
        w.f32_seq(&self.intensities);
        w.finish()
    }
}

/// `geometry_msgs/TransformStamped`: `parent_from_child`, parent `header.frame_id`.
#[derive(Debug, Clone, PartialEq)]
pub struct TransformStamped {
    /// Time and parent frame.
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// The child's origin in the parent frame (m).
    pub translation: [f64; 3],
    /// The child's orientation in the parent frame, quaternion x, y, z, w.
    pub rotation: [f64; 4],
}

/// `tf2_msgs/TFMessage`: a list of transforms.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

impl TfMessage {
    /// Decodes a CDR message.
    pub fn decode(data: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(data)?;
        // A transform holds at least 8 + 4 + 4 + 56 bytes.
        let n = r.seq_len("transforms", 72)?;
        let mut transforms = Vec::with_capacity(n);
        for _ in 0..n {
            transforms.push(TransformStamped {
                header: Header::read(&mut r)?,
                child_frame_id: r.string("child_frame_id")?,
                translation: r.f64_array("translation")?,
                rotation: r.f64_array("rotation")?,
            });
        }
        Ok(Self { transforms })
    }

    /// Encodes as a CDR message.
    pub fn encode(&self) -> Vec<u8> {
        let mut w = CdrWriter::new();
        w.seq_len(self.transforms.len());
        for t in &self.transforms {
            t.header.write(&mut w);
            w.string(&t.child_frame_id);
            w.f64_array(&t.translation);
            w.f64_array(&t.rotation);
        }
        w.finish()
    }
}

/// The header at the start of any stamped message (image, camera info, IMU, scan).
pub fn leading_header(data: &[u8]) -> Result<Header, CdrError> {
    Header::read(&mut CdrReader::new(data)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(sec: i32, nanosec: u32, frame: &str) -> Header {
        Header {
            stamp: Time { sec, nanosec },
            frame_id: frame.into(),
        }
    }

    #[test]
    fn every_message_round_trips() {
        let img = ImageMsg {
            header: header(1, 2, "cam"),
            height: 2,
            width: 3,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 9,
            data: &[7; 18],
        };
        assert_eq!(ImageMsg::decode(&img.encode()).unwrap(), img);
        let c = CompressedImageMsg {
            header: header(3, 4, "cam"),
            format: "png".into(),
            data: &[1, 2],
        };
        assert_eq!(CompressedImageMsg::decode(&c.encode()).unwrap(), c);
        let info = CameraInfoMsg {
            header: header(5, 6, "cam"),
            height: 480,
            width: 640,
            distortion_model: "plumb_bob".into(),
            d: vec![0.1, -0.2, 0.0, 0.0, 0.05],
            k: [535.4, 0.0, 320.1, 0.0, 539.2, 247.6, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [1.0; 12],
            binning: [0, 0],
            roi: ([0, 0, 0, 0], 0),
        };
        assert_eq!(CameraInfoMsg::decode(&info.encode()).unwrap(), info);
        let imu = ImuMsg {
            header: header(7, 8, "imu"),
            orientation: [0.0, 0.0, 0.0, 1.0],
            orientation_covariance: [-1.0; 9],
            angular_velocity: [0.1, 0.2, 0.3],
            angular_velocity_covariance: [0.0; 9],
            linear_acceleration: [0.0, -9.81, 0.2],
            linear_acceleration_covariance: [0.0; 9],
        };
        assert_eq!(ImuMsg::decode(&imu.encode()).unwrap(), imu);
        let scan = LaserScanMsg {
            header: header(9, 10, "laser"),
            angle_min: -2.0,
            angle_max: 2.0,
            angle_increment: 0.5,
            time_increment: 0.0,
            scan_time: 0.1,
            range_min: 0.02,
            range_max: 5.6,
            ranges: vec![1.0, f32::NAN, 2.0],
            intensities: vec![],
        };
        let back = LaserScanMsg::decode(&scan.encode()).unwrap();
        assert_eq!(back.ranges[0], 1.0);
        assert!(back.ranges[1].is_nan());
        assert_eq!(back.header, scan.header);
        let tf = TfMessage {
            transforms: vec![TransformStamped {
                header: header(11, 12, "world"),
                child_frame_id: "groundtruth".into(),
                translation: [1.0, 2.0, 3.0],
                rotation: [0.0, 0.0, 0.0, 1.0],
            }],
        };
        assert_eq!(TfMessage::decode(&tf.encode()).unwrap(), tf);
        assert_eq!(leading_header(&img.encode()).unwrap(), img.header);
    }

    #[test]
    fn decimal_stamps_are_exact() {
        let t = Time::parse_decimal("1341841873.273798").unwrap();
        assert_eq!((t.sec, t.nanosec), (1_341_841_873, 273_798_000));
        assert_eq!(Time::parse_decimal("12").unwrap().nanosec, 0);
        assert!(Time::parse_decimal("1.2345678901").is_none());
        assert!(Time::parse_decimal("-1.5").is_none());
        assert!(Time::parse_decimal("1.2e3").is_none());
        let f = Time::from_seconds(1.9999999999);
        assert_eq!((f.sec, f.nanosec), (2, 0));
        let f = Time::from_seconds(1_341_841_873.273_798);
        assert_eq!((f.sec, f.nanosec), (1_341_841_873, 273_798_000));
    }
}
