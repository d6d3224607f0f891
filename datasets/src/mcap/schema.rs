//! The `ros2msg` schema texts of the ROS 2 messages stride writes, as `ros2 bag` records
//! them: the message's definition, then each type it uses after a separator line.

const SEPARATOR: &str =
    "================================================================================\n";

fn schema(body: &str, deps: &[(&str, &str)]) -> String {
    let mut s = body.to_owned();
    for (name, text) in deps {
        s.push_str(SEPARATOR);
        s.push_str("MSG: ");
        s.push_str(name);
        s.push('\n');
        s.push_str(text);
    }
    s
}

const TIME: (&str, &str) = ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n");
const HEADER: (&str, &str) = (
    "std_msgs/Header",
    "builtin_interfaces/Time stamp\nstring frame_id\n",
);
const VECTOR3: (&str, &str) = ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n");
const QUATERNION: (&str, &str) = (
    "geometry_msgs/Quaternion",
    "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
);

/// The message types stride writes, with their `ros2msg` schema names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ros2Type {
    /// `sensor_msgs/msg/Image`.
    Image,
    /// `sensor_msgs/msg/CompressedImage`.
    CompressedImage,
    /// `sensor_msgs/msg/CameraInfo`.
    CameraInfo,
    /// `sensor_msgs/msg/Imu`.
    Imu,
    /// `sensor_msgs/msg/LaserScan`.
    LaserScan,
    /// `tf2_msgs/msg/TFMessage`.
    TfMessage,
}

impl Ros2Type {
    /// The schema name, as `ros2 bag` records it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Image => "sensor_msgs/msg/Image",
            Self::CompressedImage => "sensor_msgs/msg/CompressedImage",
            Self::CameraInfo => "sensor_msgs/msg/CameraInfo",
            Self::Imu => "sensor_msgs/msg/Imu",
            Self::LaserScan => "sensor_msgs/msg/LaserScan",
            Self::TfMessage => "tf2_msgs/msg/TFMessage",
        }
    }

    /// The type a schema name stands for (`sensor_msgs/msg/Image` or `sensor_msgs/Image`).
    pub fn from_name(name: &str) -> Option<Self> {
        let short = name.replace("/msg/", "/");
        [
            Self::Image,
            Self::CompressedImage,
            Self::CameraInfo,
            Self::Imu,
            Self::LaserScan,
            Self::TfMessage,
        ]
        .into_iter()
        .find(|t| t.name().replace("/msg/", "/") == short)
    }

    /// The `ros2msg` schema text: the definition, then each type it uses.
    pub fn schema_text(self) -> String {
        match self {
            Self::Image => schema(
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
                 uint8 is_bigendian\nuint32 step\nuint8[] data\n",
                &[HEADER, TIME],
            ),
            Self::CompressedImage => schema(
                "std_msgs/Header header\nstring format\nuint8[] data\n",
                &[HEADER, TIME],
            ),
            Self::CameraInfo => schema(
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
                 float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n\
                 uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
                &[
                    HEADER,
                    TIME,
                    (
                        "sensor_msgs/RegionOfInterest",
                        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\n\
                         bool do_rectify\n",
                    ),
                ],
            ),
            Self::Imu => schema(
                "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n\
                 float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n\
                 float64[9] angular_velocity_covariance\n\
                 geometry_msgs/Vector3 linear_acceleration\n\
                 float64[9] linear_acceleration_covariance\n",
                &[HEADER, TIME, QUATERNION, VECTOR3],
            ),
            Self::LaserScan => schema(
                "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\n\
                 float32 angle_increment\nfloat32 time_increment\nfloat32 scan_time\n\
                 float32 range_min\nfloat32 range_max\nfloat32[] ranges\nfloat32[] intensities\n",
                &[HEADER, TIME],
            ),
            Self::TfMessage => schema(
                "geometry_msgs/TransformStamped[] transforms\n",
                &[
                    (
                        "geometry_msgs/TransformStamped",
                        "std_msgs/Header header\nstring child_frame_id\n\
                         geometry_msgs/Transform transform\n",
                    ),
                    HEADER,
                    TIME,
                    (
                        "geometry_msgs/Transform",
                        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
                    ),
                    VECTOR3,
                    QUATERNION,
                ],
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schema_names_resolve_with_or_without_msg() {
        assert_eq!(
            Ros2Type::from_name("sensor_msgs/Image"),
            Some(Ros2Type::Image)
        );
        assert_eq!(
            Ros2Type::from_name("tf2_msgs/msg/TFMessage"),
            Some(Ros2Type::TfMessage)
        );
        assert_eq!(Ros2Type::from_name("std_msgs/msg/String"), None);
        assert!(Ros2Type::CameraInfo
            .schema_text()
            .contains("MSG: sensor_msgs/RegionOfInterest"));
    }
}
