"""A camera's Image and CameraInfo that only members composed into the plant read (they take
the tick's values, plant.camera_handover) are not encoded; a subscriber that comes gets
every frame from then on, the bytes and attachments of a run read all along."""
from __future__ import annotations

from bus import codec
from plant.core import step

from .test_core import _world
from .test_outbox import _Members, _published

CAMERA = ("follower/camera/image_raw", "follower/camera/camera_info")


class _CameraMembers(_Members):
    """One lockstep member composed into the plant, ``follow``, reading the follower's
    camera and nothing else."""

    NODE = "follow"

    def reads(self, key: str) -> bool:
        return key in CAMERA


def _run(tmp_path, read: set[str], members: _CameraMembers, comes=None) -> list:
    return [p for p in _published(tmp_path, read, composed=members, comes=comes,
                                  spec=_world("follow", tmp_path)) if p[0] in CAMERA]


def test_camera_messages_only_composed_members_read_are_not_encoded(tmp_path, monkeypatch):
    """The follow's world, its follower's camera read by a composed member: with a subscriber
    every frame's Image and CameraInfo are encoded and put; without one neither is made nor
    put, and the member gets the same messages as values."""
    made: list[str] = []
    image, info = codec.image, step._info_bytes

    def counted_image(*args, **kw):
        made.append("image")
        return image(*args, **kw)

    def counted_info(*args, **kw):
        made.append("info")
        return info(*args, **kw)
    monkeypatch.setattr(codec, "image", counted_image)
    monkeypatch.setattr(step, "_info_bytes", counted_info)
    clock = "sim/clock"
    ref_members = _CameraMembers()
    ref = _run(tmp_path, {clock, *CAMERA}, ref_members)
    frames = sum(k == CAMERA[0] for k, _, _ in ref)
    assert frames >= 3 and made.count("image") == frames
    assert made.count("info") == len(ref) - frames
    ref_msgs = [(k, codec.encode(m)) for k, _, m in ref_members.got]
    assert ref_msgs == [(k, d) for k, d, _ in ref]

    made.clear()
    members = _CameraMembers()
    assert _run(tmp_path, {clock}, members) == []
    assert made == []                                # neither message's bytes made
    assert all(d is step.UNENCODED for _, d, _ in members.got)
    assert [(k, codec.encode(m)) for k, _, m in members.got] == ref_msgs


def test_a_late_camera_subscriber_gets_every_frame_from_then_on(tmp_path):
    """A subscriber that comes before a tick's sensing or between it and the puts gets that
    tick's frame and every later one, bytes and attachments as if read all along."""
    clock = "sim/clock"
    ref_members = _CameraMembers()
    ref = _run(tmp_path, {clock, *CAMERA}, ref_members)
    ref_msgs = [(k, codec.encode(m)) for k, _, m in ref_members.got]
    stamps = sorted({codec.parse_attachment(a).t_ns for k, _, a in ref if k == CAMERA[0]})
    at = stamps[len(stamps) // 2]                    # (a tick whose frame is due)
    for mid in (False, True):                        # before the tick's sensing, or after it
        members = _CameraMembers()
        got = _run(tmp_path, {clock}, members, comes=(at // 20_000_000, set(CAMERA), mid))
        assert got and got == [p for p in ref if codec.parse_attachment(p[2]).t_ns >= at], mid
        assert [(k, codec.encode(m)) for k, _, m in members.got] == ref_msgs, mid
