"""The demo recording: two synthetic cameras watching incoming balls, as a rosbag2 bag.

Layout of a recording folder::

    recording.json   what it was made from (balls, seed, plane, size, imaging, colour) and
                     each ball's truth
    rig.yaml         the rig (cameras' poses, sources /cam0/image_raw, /cam1/image_raw)
    cam0.yaml ...    camera_info YAML per camera
    bag/             rosbag2 (MCAP): /camN/image_raw (sensor_msgs/Image, bgr8) and
                     /camN/camera_info (sensor_msgs/CameraInfo) per frame, stamped with the
                     middle of the exposure
    cam0.avi ...     the same frames as MJPG video per camera (what a camera sends)
    rig_video.yaml   the rig with the videos as sources (perception_node reads them as
                     cameras); video time 0 is scene time ``video_t0`` of recording.json

It is rendered with tt_perception's scene generator (``tt_perception.synth``) and written
with the ``rosbags`` library, so it is a plain rosbag2 bag that a full ROS 2 install plays
too. It is built on first use and cached: the folder is reused while ``recording.json``
matches the request. Pure module (no rclpy).
"""

from dataclasses import dataclass
import json
import pathlib
import shutil

import numpy as np
from tt_prediction.ball import ModelParams

from tt_perception import synth

from .scenario import Ball, demo_balls, fly

FORMAT_VERSION = 3
STAMP_BASE_S = 1_700_000_000
"""Recording time zero as a ROS time (s): stamps are this plus the scene time."""
LEAD_IN_S = 0.2
"""Scene before the first launch, s."""


@dataclass
class Recording:
    path: pathlib.Path
    truths: list
    params: ModelParams
    image_topics: tuple
    video_rig: pathlib.Path = None
    """Rig of the videos (cameras read in-process)."""
    video_t0: float = 0.0
    """Scene time of the videos' first frame, s."""
    colour: str = 'white'
    """The balls' colour (perception_node's ``ball_colour``)."""


def replay_publishers(node, image_topics, prefix=''):
    """Publishers on the rclpy ``node`` to replay a recording's bag: Image on each of
    ``image_topics`` and CameraInfo beside it, named ``prefix`` + the bag's topic and keyed by
    the bag's topic (they publish the bag's serialized messages as they are)."""
    from sensor_msgs.msg import CameraInfo, Image
    from tt_perception.sources import camera_info_topic

    publishers = {}
    for topic in image_topics:
        publishers[topic] = node.create_publisher(Image, prefix + topic, 10)
        info = camera_info_topic(topic)
        publishers[info] = node.create_publisher(CameraInfo, prefix + info, 10)
    return publishers


def _camera_info(typestore, cam, header):
    """sensor_msgs/CameraInfo of a tt_perception Camera (plumb-bob, no rectification)."""
    CameraInfo = typestore.types['sensor_msgs/msg/CameraInfo']
    RegionOfInterest = typestore.types['sensor_msgs/msg/RegionOfInterest']
    K = np.asarray(cam.K, dtype=float)
    return CameraInfo(header=header, height=cam.height, width=cam.width,
                      distortion_model='plumb_bob', d=np.asarray(cam.dist, dtype=float),
                      k=K.ravel(), r=np.eye(3).ravel(),
                      p=np.hstack([K, np.zeros((3, 1))]).ravel(), binning_x=0, binning_y=0,
                      roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0,
                                           do_rectify=False))


def write_bag(bag_dir, rig, frames):
    """Write ``frames`` ((t, camera_index, frame) in time order, frame BGR uint8 or None for
    a dropped frame) as Image + CameraInfo per camera into a new MCAP bag at ``bag_dir``.
    Returns the number of images written."""
    from rosbags.typesys import Stores, get_typestore
    from tt_perception.sources import camera_info_topic
    from tt_ros.bagfile import BagWriter

    typestore = get_typestore(Stores.ROS2_JAZZY)
    Image = typestore.types['sensor_msgs/msg/Image']
    Header = typestore.types['std_msgs/msg/Header']
    Time = typestore.types['builtin_interfaces/msg/Time']
    count = 0
    writer = BagWriter(bag_dir, 'mcap')
    try:
        connections = []
        for cam in rig.cameras:
            connections.append((writer.add_topic(cam.source, Image.__msgtype__),
                                writer.add_topic(camera_info_topic(cam.source),
                                                 'sensor_msgs/msg/CameraInfo')))
        for t, k, frame in frames:
            if frame is None:
                continue
            cam = rig.cameras[k]
            stamp_ns = int(round((STAMP_BASE_S + t) * 1e9))
            header = Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
                            frame_id=cam.name)
            image = Image(header=header, height=frame.shape[0], width=frame.shape[1],
                          encoding='bgr8', is_bigendian=0, step=frame.shape[1] * 3,
                          data=np.ascontiguousarray(frame).reshape(-1))
            image_conn, info_conn = connections[k]
            writer.write(image_conn, stamp_ns,
                         typestore.serialize_cdr(image, Image.__msgtype__))
            writer.write(info_conn, stamp_ns,
                         typestore.serialize_cdr(_camera_info(typestore, cam, header),
                                                 'sensor_msgs/msg/CameraInfo'))
            count += 1
    finally:
        writer.close()
    return count


IMAGING = synth.IMAGING
COLOURS = tuple(synth.BALL_COLOURS)
EXPOSURE_S = {'clean': 1.5e-3, 'hall': 2e-3}
"""The cameras' exposure (the ball's motion blur), s: issue 15's 2 ms in a hall."""


def _request(balls, hit_plane_x, seed, imaging, colour):
    return {'format': FORMAT_VERSION, 'balls': balls, 'hit_plane_x': hit_plane_x, 'seed': seed,
            'width': 640, 'height': 480, 'fps': 150.0, 'imaging': imaging, 'colour': colour,
            'exposure': EXPOSURE_S[imaging]}


def ensure_recording(path, balls=4, hit_plane_x=-1.5, seed=7, params=None, imaging='clean',
                     colour='white'):
    """The recording at ``path``, rendered and written first if absent or made differently.

    ``imaging`` (:data:`IMAGING`) and ``colour`` (:data:`COLOURS`, the balls') choose the
    scene generator's rendering. Truth times are scene times: message stamps minus
    STAMP_BASE_S. Written to a temporary folder and renamed: a half-written recording never
    stays.
    """
    from tt_perception.camera import load_rig

    params = params or ModelParams()
    path = pathlib.Path(path)
    if imaging not in IMAGING or colour not in COLOURS:
        raise ValueError(f'imaging must be one of {IMAGING} and colour one of {COLOURS}, '
                         f'not {imaging!r} and {colour!r}')
    request = _request(balls, hit_plane_x, seed, imaging, colour)
    meta_file = path / 'recording.json'
    if not (meta_file.exists() and json.loads(meta_file.read_text())['request'] == request):
        # The balls first: a plane they do not reach raises before anything is written.
        truths = demo_balls(balls, hit_plane_x, seed=seed, params=params)
        tmp = path.with_name(path.name + '.partial')
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        try:
            _render(path, tmp, truths, request, params, seed, colour, imaging, balls)
        except BaseException:         # Ctrl-C while rendering left 164 MB behind
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    rig = load_rig(str(path / 'rig.yaml'))
    meta = json.loads(meta_file.read_text())
    truths = [fly(Ball(ball['launch_time'], np.array(ball['launch_state'])), params,
                  hit_plane_x) for ball in meta['truth']]
    return Recording(path, truths, params, tuple(cam.source for cam in rig.cameras),
                     path / 'rig_video.yaml', meta['video_t0'], colour)


def _render(path, tmp, truths, request, params, seed, colour, imaging, balls):
    """Render the recording into the folder ``tmp`` and rename it to ``path``."""
    from tt_perception.camera import load_rig, save_rig

    rig = load_rig(synth.make_rig(str(tmp), request['width'], request['height'],
                                  request['fps']))
    last = truths[-1]
    frames, _ = synth.render_balls(
        rig, [tr.ball.launch_state for tr in truths],
        [tr.ball.launch_time for tr in truths],
        duration=last.hit_time - last.ball.launch_time + 0.1, lead_in=LEAD_IN_S,
        params=params, seed=seed, colour=colour, imaging=imaging,
        exposure=request['exposure'])
    print(f'tt-demo: rendering {balls} balls through {len(rig.cameras)} cameras into '
          f'{path / "bag"} (once; cached)', flush=True)
    with synth.CameraVideos(tmp, rig) as videos:      # the same frames as MJPG videos
        images = write_bag(str(tmp / 'bag'), rig, videos.tee(frames))
    video_t0 = truths[0].ball.launch_time - LEAD_IN_S
    for cam in rig.cameras:
        cam.source = f'{cam.name}.avi'
        cam.time_offset = 0.0
    save_rig(str(tmp / 'rig_video.yaml'), rig)
    truth = [{'launch_time': tr.ball.launch_time,
              'launch_state': tr.ball.launch_state.tolist(),
              'bounce_time': tr.bounce_time, 'bounce_point': tr.bounce_point.tolist(),
              'bounce_zone': tr.bounce_zone, 'hit_time': tr.hit_time,
              'hit_state': tr.hit_state.tolist()} for tr in truths]
    meta = {'request': request, 'images': images, 'stamp_base_s': STAMP_BASE_S,
            'video_t0': video_t0, 'truth': truth}
    (tmp / 'recording.json').write_text(json.dumps(meta, indent=1))
    shutil.rmtree(path, ignore_errors=True)
    tmp.rename(path)
