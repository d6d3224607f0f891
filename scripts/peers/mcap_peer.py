"""The independent side of stride's MCAP interoperability test (tests/mcap.rs), using the
Python `mcap` and `mcap-ros2-support` packages (a throwaway venv, never a project dependency).

    python mcap_peer.py write OUT.mcap FRAMES   a ROS 2 RGB-D log stride must read
    python mcap_peer.py read FILE.mcap          what a reader sees in a log, as JSON (ROS 2
                                                CDR messages decoded by mcap-ros2-support,
                                                Foxglove JSON messages by json)

The written log (zstd chunks, the packages' defaults) holds FRAMES frames at 30 Hz from
1700000000.123456789 s: /cam/color (bgr8, 160x120, step padded to 488 bytes), /cam/depth
(32FC1, metres; NaN at even (u, v)), /cam/color/camera_info, /imu (in the colour frame) and
/tf (odom -> cam_gt). Pixel values follow the formulas in `pattern` so that the Rust side can
check every one.
"""
import base64
import json
import math
import struct
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

W, H, STEP = 160, 120, 488
T0_SEC, T0_NSEC = 1700000000, 123456789
FX, FY, CX, CY = 150.0, 151.0, 79.5, 59.5

HEADER = """
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
IMAGE = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n"
         "uint8 is_bigendian\nuint32 step\nuint8[] data\n") + HEADER
INFO = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
        "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
        "uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n" + HEADER +
        "================================================================================\n"
        "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 height\n"
        "uint32 width\nbool do_rectify\n")
VEC = ("================================================================================\n"
       "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n")
QUAT = ("================================================================================\n"
        "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n")
IMU = ("std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
       "float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
       "float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n"
       "float64[9] linear_acceleration_covariance\n" + HEADER + QUAT + VEC)
TF = ("geometry_msgs/TransformStamped[] transforms\n"
      "================================================================================\n"
      "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n"
      "geometry_msgs/Transform transform\n" + HEADER +
      "================================================================================\n"
      "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\n"
      "geometry_msgs/Quaternion rotation\n" + VEC + QUAT)


def stamp(k):
    ns = T0_NSEC + k * 33_333_333
    return {"sec": T0_SEC + ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def pattern(k, u, v):
    """(r, g, b) and depth in metres (NaN: no return) of pixel (u, v) in frame k."""
    rgb = ((u + k) % 256, v % 256, (u * v + k) % 256)
    depth = math.nan if (u % 2 == 0 and v % 2 == 0) else 0.5 + 0.001 * (u + v) + 0.01 * k
    return rgb, depth


def write(path, frames):
    with open(path, "wb") as f:
        w = Writer(f)
        s_img = w.register_msgdef("sensor_msgs/msg/Image", IMAGE)
        s_info = w.register_msgdef("sensor_msgs/msg/CameraInfo", INFO)
        s_imu = w.register_msgdef("sensor_msgs/msg/Imu", IMU)
        s_tf = w.register_msgdef("tf2_msgs/msg/TFMessage", TF)
        for k in range(frames):
            st = stamp(k)
            t_ns = st["sec"] * 1_000_000_000 + st["nanosec"]
            color = bytearray(STEP * H)
            depth = bytearray()
            for v in range(H):
                for u in range(W):
                    (r, g, b), d = pattern(k, u, v)
                    color[v * STEP + 3 * u: v * STEP + 3 * u + 3] = bytes((b, g, r))
                    depth += struct.pack("<f", d)
            hdr = {"stamp": st, "frame_id": "cam_color"}
            w.write_message("/cam/color", s_img, {
                "header": hdr, "height": H, "width": W, "encoding": "bgr8",
                "is_bigendian": 0, "step": STEP, "data": bytes(color)}, log_time=t_ns,
                publish_time=t_ns)
            w.write_message("/cam/depth", s_img, {
                "header": hdr, "height": H, "width": W, "encoding": "32FC1",
                "is_bigendian": 0, "step": 4 * W, "data": bytes(depth)}, log_time=t_ns,
                publish_time=t_ns)
            if k == 0:
                w.write_message("/cam/color/camera_info", s_info, {
                    "header": hdr, "height": H, "width": W, "distortion_model": "plumb_bob",
                    "d": [0.0] * 5, "k": [FX, 0, CX, 0, FY, CY, 0, 0, 1],
                    "r": [1, 0, 0, 0, 1, 0, 0, 0, 1],
                    "p": [FX, 0, CX, 0, 0, FY, CY, 0, 0, 0, 1, 0], "binning_x": 0,
                    "binning_y": 0, "roi": {"x_offset": 0, "y_offset": 0, "height": 0,
                                            "width": 0, "do_rectify": False}},
                    log_time=t_ns, publish_time=t_ns)
            w.write_message("/imu", s_imu, {
                "header": hdr, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1},
                "orientation_covariance": [-1] + [0] * 8,
                "angular_velocity": {"x": 0, "y": 0, "z": 0},
                "angular_velocity_covariance": [0] * 9,
                "linear_acceleration": {"x": 0.1 * k, "y": -9.81, "z": 0.2},
                "linear_acceleration_covariance": [0] * 9}, log_time=t_ns, publish_time=t_ns)
            w.write_message("/tf", s_tf, {"transforms": [{
                "header": {"stamp": st, "frame_id": "odom"}, "child_frame_id": "cam_gt",
                "transform": {"translation": {"x": 0.01 * k, "y": 0.0, "z": 1.0},
                              "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}}]},
                log_time=t_ns, publish_time=t_ns)
        w.finish()


def foxglove_summary(schema, m):
    """The fields of a Foxglove JSON message that the Rust side checks."""
    if schema == "foxglove.FrameTransform":
        return {"parent": m["parent_frame_id"], "child": m["child_frame_id"],
                "translation": [m["translation"][k] for k in "xyz"],
                "timestamp": [m["timestamp"]["sec"], m["timestamp"]["nsec"]]}
    if schema == "foxglove.PosesInFrame":
        return {"frame_id": m["frame_id"], "poses": len(m["poses"]),
                "last": [m["poses"][-1]["position"][k] for k in "xyz"] if m["poses"] else None}
    data = base64.b64decode(m["data"])
    fields = [(f["name"], f["offset"], f["type"]) for f in m["fields"]]
    if schema == "foxglove.PointCloud":
        n = len(data) // m["point_stride"]
        pts = [struct.unpack_from("<3f", data, i * m["point_stride"]) for i in range(n)]
        return {"frame_id": m["frame_id"], "fields": fields, "points": n,
                "mean": [sum(p[i] for p in pts) / max(n, 1) for i in range(3)]}
    if schema == "foxglove.Grid":
        rows = len(data) // m["row_stride"]
        cells = [struct.unpack_from("<2f", data, r * m["row_stride"] + c * m["cell_stride"])
                 for r in range(rows) for c in range(m["column_count"])]
        known = [h for h, _ in cells if not math.isnan(h)]
        return {"frame_id": m["frame_id"], "fields": fields, "columns": m["column_count"],
                "rows": rows, "cell_size": [m["cell_size"]["x"], m["cell_size"]["y"]],
                "corner": [m["pose"]["position"][k] for k in "xyz"], "known": len(known),
                "mean_elevation": sum(known) / max(len(known), 1)}
    return {}


def read(path):
    out = {"channels": {}}
    factory = DecoderFactory()
    decoders = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            c = out["channels"].setdefault(channel.topic, {
                "schema": schema.name, "schema_encoding": schema.encoding,
                "message_encoding": channel.message_encoding,
                "metadata": dict(channel.metadata), "count": 0, "stamps": []})
            c["count"] += 1
            if channel.message_encoding == "json":
                m = json.loads(message.data)
                if c["count"] == 1:
                    c["first"] = foxglove_summary(schema.name, m)
                    c["schema_title"] = json.loads(schema.data).get("title")
                continue
            if schema.id not in decoders:
                decoders[schema.id] = factory.decoder_for(channel.message_encoding, schema)
            m = decoders[schema.id](message.data)
            if hasattr(m, "header"):
                c["stamps"].append([m.header.stamp.sec, m.header.stamp.nanosec])
                if c["count"] == 1:
                    c["frame_id"] = m.header.frame_id
                if message.log_time != m.header.stamp.sec * 10**9 + m.header.stamp.nanosec:
                    c["log_time_differs"] = True
            if c["count"] > 1:
                continue
            if schema.name == "sensor_msgs/msg/Image":
                c["first"] = {"height": m.height, "width": m.width, "encoding": m.encoding,
                              "step": m.step, "bytes": len(m.data),
                              "head": list(m.data[:12])}
            elif schema.name == "sensor_msgs/msg/CameraInfo":
                c["first"] = {"k": list(m.k), "d": list(m.d), "model": m.distortion_model,
                              "height": m.height, "width": m.width}
            elif schema.name == "tf2_msgs/msg/TFMessage":
                t = m.transforms[0]
                c["first"] = {"parent": t.header.frame_id, "child": t.child_frame_id,
                              "translation": [t.transform.translation.x,
                                              t.transform.translation.y,
                                              t.transform.translation.z],
                              "rotation": [t.transform.rotation.x, t.transform.rotation.y,
                                           t.transform.rotation.z, t.transform.rotation.w]}
            elif schema.name == "sensor_msgs/msg/LaserScan":
                c["first"] = {"beams": len(m.ranges), "angle_min": m.angle_min,
                              "angle_increment": m.angle_increment,
                              "returns": sum(1 for r in m.ranges if r == r)}
            elif schema.name == "sensor_msgs/msg/Imu":
                a = m.linear_acceleration
                c["first"] = {"linear_acceleration": [a.x, a.y, a.z]}
    print(json.dumps(out))


if __name__ == "__main__":
    if sys.argv[1] == "write":
        write(sys.argv[2], int(sys.argv[3]))
    elif sys.argv[1] == "read":
        read(sys.argv[2])
    else:
        sys.exit(__doc__)
