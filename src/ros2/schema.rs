//! The `ros2msg` schema texts of the messages tricons writes and reads, as rosbag2 stores
//! them in MCAP: the type's fields, then each nested type once after a line of 80 `=` and
//! `MSG: pkg/Type`. Comments of the upstream `.msg` files are left out (readers ignore them).

/// MCAP schema encoding of ROS 2 message definitions.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// MCAP message encoding of ROS 2 payloads.
pub const MESSAGE_ENCODING: &str = "cdr";
/// MCAP profile of ROS 2 bags.
pub const PROFILE: &str = "ros2";

/// `sensor_msgs/msg/Image`.
pub const IMAGE: (&str, &str) = ("sensor_msgs/msg/Image", include_str!("msgdefs/sensor_msgs__Image.msg"));
/// `sensor_msgs/msg/CompressedImage`.
pub const COMPRESSED_IMAGE: (&str, &str) =
    ("sensor_msgs/msg/CompressedImage", include_str!("msgdefs/sensor_msgs__CompressedImage.msg"));
/// `sensor_msgs/msg/CameraInfo`.
pub const CAMERA_INFO: (&str, &str) =
    ("sensor_msgs/msg/CameraInfo", include_str!("msgdefs/sensor_msgs__CameraInfo.msg"));
/// `vision_msgs/msg/Detection3DArray`.
pub const DETECTION_3D_ARRAY: (&str, &str) =
    ("vision_msgs/msg/Detection3DArray", include_str!("msgdefs/vision_msgs__Detection3DArray.msg"));
/// `visualization_msgs/msg/MarkerArray`.
pub const MARKER_ARRAY: (&str, &str) =
    ("visualization_msgs/msg/MarkerArray", include_str!("msgdefs/visualization_msgs__MarkerArray.msg"));

#[cfg(test)]
mod tests {
    use super::*;

    /// Every nested type a definition names is defined once in it (what readers that build
    /// decoders from the text, like mcap-ros2-support, need).
    #[test]
    fn every_nested_type_is_defined_once() {
        const PRIMITIVES: &[&str] = &[
            "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
            "int64", "uint64", "string",
        ];
        for (name, text) in [IMAGE, COMPRESSED_IMAGE, CAMERA_INFO, DETECTION_3D_ARRAY, MARKER_ARRAY] {
            let separator = format!("{}\nMSG: ", "=".repeat(80));
            let mut sections: Vec<(String, &str)> = Vec::new();
            for (i, part) in text.split(separator.as_str()).enumerate() {
                if i == 0 {
                    sections.push((name.replace("/msg/", "/"), part));
                } else {
                    let (head, body) = part.split_once('\n').unwrap();
                    sections.push((head.to_string(), body));
                }
            }
            let defined: Vec<&str> = sections.iter().map(|(n, _)| n.as_str()).collect();
            for (section, body) in &sections {
                let package = section.split('/').next().unwrap();
                for line in body.lines().filter(|l| !l.trim().is_empty()) {
                    let ty = line.split_whitespace().next().unwrap();
                    if line.contains('=') {
                        continue; // a constant
                    }
                    let base = ty.split('[').next().unwrap();
                    if PRIMITIVES.contains(&base) {
                        continue;
                    }
                    let full = if base.contains('/') { base.to_string() } else { format!("{package}/{base}") };
                    let count = defined.iter().filter(|d| **d == full).count();
                    assert_eq!(count, 1, "{name}: {full} (used in {section}) is defined {count} times");
                }
            }
        }
    }
}
