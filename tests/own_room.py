"""What a photographer would have of a benchmark room (bench/own_room_flow.py, shared with
bench/bench_unseen.py): re-exported for test_scene_cmd, test_own_room and test_readme_walkthrough."""
from bench.own_room_flow import (  # noqa: F401
    benchmark_camera_json, fmt, object_pose, probe_args, scene_argv, sunlit_inputs, tape_room, write_inputs)
