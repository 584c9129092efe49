"""Reading footage: videos (rotation, selection, damage, limits) and photo folders (EXIF)."""

import argparse
import struct
import warnings

import numpy as np
import pytest

from mogaface.core.errors import InputError
from mogaface.core.io.video import APPLE_FOCAL_35MM, VideoWriter
from mogaface.core.track import decode, inputs, videos
from mogaface.core.track.decode import frame_position, open_footage
from mogaface.core.track.inputs import FootageWarning, FrameSelection, upright

WIDTH, HEIGHT, COUNT = 64, 112, 12


def psnr(a, b) -> float:
    return float(10 * np.log10(255.0**2 / np.mean((a.astype(np.float64) - b) ** 2)))


def portrait_frames():
    """Upright frames with structure a codec keeps (smooth gradients, a moving bar)."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    frames = []
    for k in range(COUNT):
        rgb = np.stack([3 * x + 4 * k, 2 * y, (x + y + 9 * k) % 200 + 30], -1).astype(np.float64)
        rgb[(y // 8) % 4 == k % 4] *= 0.6
        frames.append(np.clip(rgb, 0, 255).astype(np.uint8))
    return frames


def write_clip(path, frames, **options):
    with VideoWriter(path, frames[0].shape[1], frames[0].shape[0], 30, **options) as video:
        for rgb in frames:
            video.write(rgb)
    return path


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clips")
    frames = portrait_frames()
    return {
        "frames": frames,
        "plain": write_clip(folder / "plain.mp4", frames, metadata={APPLE_FOCAL_35MM: "26"}),
        "flagged": write_clip(folder / "flagged.mp4", frames, rotation_flag=True),
        "indexed": write_clip(folder / "indexed.mp4", frames, index_first=True),
        "folder": folder,
    }


def test_a_clip_reads_back_as_written(clips):
    video = open_footage(clips["plain"])
    info = video.info
    assert (info.kind, info.frame_count, info.frame_count_exact, info.fps) == ("video", COUNT, True, 30.0)
    assert (info.width, info.height, info.codec, info.orientation) == (WIDTH, HEIGHT, "h264", 1)
    assert info.duration == pytest.approx(COUNT / 30)
    assert info.focal_35mm == 26.0 and info.focal_px == pytest.approx(26 * np.hypot(WIDTH, HEIGHT) / np.hypot(36, 24))
    frames = list(video.frames())
    assert [f.index for f in frames] == list(range(COUNT))
    assert [f.time for f in frames] == pytest.approx(np.arange(COUNT) / 30)
    assert all(f.rgb.shape == (HEIGHT, WIDTH, 3) and f.rgb.dtype == np.uint8 for f in frames)
    assert min(psnr(f.rgb, clips["frames"][f.index]) for f in frames) > 30


def test_a_rotation_flag_reads_upright(clips):
    info = open_footage(clips["flagged"]).info
    assert (info.stored_width, info.stored_height) == (HEIGHT, WIDTH)  # stored landscape
    assert (info.width, info.height, info.orientation) == (WIDTH, HEIGHT, 6)  # shown portrait
    frames = list(open_footage(clips["flagged"]).frames())
    assert len(frames) == COUNT and min(psnr(f.rgb, clips["frames"][f.index]) for f in frames) > 30
    # the track header carries the matrix a phone held upright writes (turn 90° clockwise to show)
    data = clips["flagged"].read_bytes()
    start = data.index(b"tkhd") + 4
    offset = start + (40 if data[start] == 0 else 52)
    assert struct.unpack(">9i", data[offset:offset + 36])[:5] == (0, 1 << 16, 0, -(1 << 16), 0)


def test_every_orientation_matches_pillow_and_ffmpeg():
    from PIL import Image, ImageOps

    stored = np.random.default_rng(0).integers(0, 255, (3, 5, 3), dtype=np.uint8)
    for code in range(1, 9):
        image = Image.fromarray(stored)
        image.getexif()[0x0112] = code
        assert np.array_equal(np.asarray(ImageOps.exif_transpose(image)), upright(stored, code)), code
    # display matrices: FFmpeg's av_display_rotation_set(clockwise degrees) and its flips
    for ccw, code in ((0, 1), (-90, 6), (90, 8), (180, 3)):
        assert inputs.orientation_from_display_matrix(videos.rotation_matrix(ccw)) == code
    mirrored = videos.rotation_matrix(0)
    mirrored[0] = -mirrored[0]
    assert inputs.orientation_from_display_matrix(mirrored) == 2
    assert inputs.orientation_from_rotate_tag("90") == 6 and inputs.orientation_from_rotate_tag("270") == 8
    with pytest.raises(InputError, match="multiple of 90"):
        inputs.orientation_from_display_matrix(videos.rotation_matrix(30))


def test_frame_range_stride_and_rate_select_the_right_frames(clips):
    video = open_footage(clips["plain"])

    def picked(**selection):
        return [(f.index, round(f.time * 30)) for f in video.frames(FrameSelection(**selection))]

    assert picked(start=2, end=10, stride=3) == [(2, 2), (5, 5), (8, 8)]
    assert picked(start_time=0.1, end_time=0.3) == [(i, i) for i in range(3, 9)]
    assert picked(fps=10) == [(i, i) for i in (0, 3, 6, 9)]
    assert [i for i, _ in picked(fps=12)] == [0, 3, 5, 8, 10]  # dropped evenly: 2.5 frames apart
    assert [i for i, _ in picked(start=1, fps=15, stride=2)] == [1, 5, 9]  # range, then rate, then stride
    assert picked(fps=60) == [(i, i) for i in range(COUNT)]  # never duplicated
    sizes = {f.rgb.shape for f in video.frames(FrameSelection(end=2), size=56)}
    flagged = {f.rgb.shape for f in open_footage(clips["flagged"]).frames(FrameSelection(end=2), size=56)}
    assert sizes == flagged == {(56, 32, 3)}
    with pytest.raises(InputError, match="stride"):
        next(video.frames(FrameSelection(stride=0)))


def test_command_line_positions():
    assert frame_position("90") == ("frame", 90) and frame_position("2.5s") == ("seconds", 2.5)
    for bad in ("-1", "x", "-2s", "nans"):
        with pytest.raises(argparse.ArgumentTypeError):
            frame_position(bad)
    parser = argparse.ArgumentParser()
    decode.add_footage_arguments(parser)
    args = parser.parse_args(["--start", "1.5s", "--end", "40", "--stride", "2", "--fps", "15"])
    assert decode.selection_from_arguments(args) == FrameSelection(end=40, start_time=1.5, stride=2, fps=15.0)


def test_a_cut_recording_without_its_index_is_refused(clips, tmp_path):
    data = clips["plain"].read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])  # the index (moov) comes last: cut away
    with pytest.raises(InputError, match="'moov'.*cut off"):
        open_footage(cut)


def test_a_damaged_clip_keeps_the_frames_before_the_damage(clips, tmp_path):
    data = clips["indexed"].read_bytes()
    mdat = data.index(b"mdat")
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: mdat + (len(data) - mdat) * 6 // 10])
    video = open_footage(cut)
    assert video.info.frame_count == COUNT  # as the index declares
    with pytest.warns(FootageWarning, match=r"damaged \(the packet at .* is incomplete or corrupt\): read the first"):
        frames = list(video.frames())
    assert 0 < len(frames) < COUNT and [f.index for f in frames] == list(range(len(frames)))
    assert min(psnr(f.rgb, clips["frames"][f.index]) for f in frames) > 30
    assert video.damage.startswith("damaged")
    # bytes flipped inside a frame of a complete file: the frames before it
    import av

    with av.open(str(clips["plain"])) as container:
        packets = [(p.pos, p.size) for p in container.demux(video=0) if p.size]
    flipped = bytearray(clips["plain"].read_bytes())
    position, size = packets[6]
    flipped[position + size // 2: position + size // 2 + 8] = bytes(8)
    (tmp_path / "flipped.mp4").write_bytes(bytes(flipped))
    with pytest.warns(FootageWarning, match="damaged"):
        kept = list(open_footage(tmp_path / "flipped.mp4").frames())
    assert 0 < len(kept) < COUNT and min(psnr(f.rgb, clips["frames"][f.index]) for f in kept) > 30
    # cut inside the first frame: nothing to keep
    first = tmp_path / "first.mp4"
    first.write_bytes(data[: mdat + 64])
    with pytest.raises(InputError, match="no frame could be decoded"):
        open_footage(first)


def test_what_is_not_a_video_is_refused(clips, tmp_path):
    import av

    empty = tmp_path / "empty.mp4"
    with av.open(str(empty), "w") as container:  # a recording stopped before its first frame
        stream = container.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        stream.codec_context.open()
        container.start_encoding()
    with pytest.raises(InputError, match="field 'streams': holds no video stream"):
        open_footage(empty)
    text = tmp_path / "notes.mp4"
    text.write_text("not a video\n" * 20)
    with pytest.raises(InputError, match="notes.mp4: not a video FFmpeg can read"):
        open_footage(text)
    (tmp_path / "zero.mov").write_bytes(b"")
    with pytest.raises(InputError, match="zero.mov"):
        open_footage(tmp_path / "zero.mov")
    with pytest.raises(InputError, match="file not found"):
        open_footage(tmp_path / "missing.mp4")


def test_frames_above_8k_are_refused_before_decoding(clips, tmp_path, monkeypatch):
    import av

    # an MP4 whose sample description declares 8704x8704: refused from its boxes, before FFmpeg opens it
    data = bytearray(clips["plain"].read_bytes())
    entry = data.index(b"stsd") + 4 + 8 + 8  # its first sample entry's payload; width and height at byte 24
    assert struct.unpack(">HH", data[entry + 24:entry + 28]) == (WIDTH, HEIGHT)
    data[entry + 24:entry + 28] = struct.pack(">HH", 8704, 8704)
    declared = tmp_path / "declared.mp4"
    declared.write_bytes(bytes(data))
    with monkeypatch.context() as patch:
        patch.setattr(av, "open", lambda *a, **k: pytest.fail("FFmpeg opened a refused video"))
        with pytest.raises(InputError, match=r"field 'frame size': declares 8704x8704 frames; the limit is 8192"):
            open_footage(declared)
    # another container: the size the stream declares once FFmpeg has opened it, before a frame is decoded
    tall = tmp_path / "tall.mkv"
    with av.open(str(tall), "w") as container:  # 16x8704: cheap to encode, one side above 8192
        stream = container.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = 16, 8704, "yuv420p"
        for frame in [av.VideoFrame.from_ndarray(np.zeros((8704, 16, 3), np.uint8), format="rgb24")] * 2 + [None]:
            container.mux(stream.encode(frame))
    monkeypatch.setattr(videos.Video, "_decoded", lambda *a, **k: pytest.fail("decoded a refused video"))
    with pytest.raises(InputError, match=r"declares 16x8704 frames; the limit is 8192 a side and 35389440 pixels"):
        open_footage(tall)
    videos.check_video_size(tall, 7680, 4320)  # 8K UHD and DCI 8K pass
    videos.check_video_size(tall, 8192, 4320)
    with pytest.raises(InputError, match="8K"):
        videos.check_video_size(tall, 8192, 4352)


def test_an_hevc_clip_reads(tmp_path):
    frames = portrait_frames()[:4]
    path = write_clip(tmp_path / "hevc.mov", frames, codec="libx265")
    video = open_footage(path)
    assert video.info.codec == "hevc" and video.info.frame_count == 4
    assert min(psnr(f.rgb, frames[f.index]) for f in video.frames()) > 30


def _jpeg(path, upright_rgb, orientation, focal=None):
    from PIL import Image

    stored = {1: upright_rgb, 6: np.rot90(upright_rgb, 1), 8: np.rot90(upright_rgb, -1)}[orientation]
    exif = Image.Exif()
    exif[0x0112] = orientation
    if focal:
        exif.get_ifd(0x8769)[0xA405] = focal
    Image.fromarray(np.ascontiguousarray(stored)).save(path, quality=95, exif=exif)


def test_a_photo_folder_reads_upright_with_its_lens(tmp_path):
    from PIL import Image

    frames = portrait_frames()
    _jpeg(tmp_path / "IMG_2.jpg", frames[0], 6, focal=26)  # portrait stored landscape
    _jpeg(tmp_path / "IMG_10.jpg", frames[1], 8, focal=26)
    Image.fromarray(frames[2][:96, :48]).save(tmp_path / "IMG_11.png")  # another size, no EXIF
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "._IMG_2.jpg").write_bytes(b"\0\5\26\7")  # a macOS companion file: hidden, skipped
    photos = open_footage(tmp_path)
    info = photos.info
    assert [p.name for p in info.photos] == ["IMG_2.jpg", "IMG_10.jpg", "IMG_11.png"]  # natural order
    assert [p.orientation for p in info.photos] == [6, 8, 1] and info.ignored == ("notes.txt",)
    assert info.sizes == {(WIDTH, HEIGHT): 2, (48, 96): 1} and info.codec == "jpeg+png"
    assert info.focal_35mm is None and [p.focal_35mm for p in info.photos] == [26.0, 26.0, None]
    got = list(photos.frames())
    assert [f.time for f in got] == [None] * 3
    assert psnr(got[0].rgb, frames[0]) > 30 and psnr(got[1].rgb, frames[1]) > 30
    assert np.array_equal(got[2].rgb, frames[2][:96, :48])
    assert [f.rgb.shape for f in photos.frames(FrameSelection(start=1), size=32)] == [(32, 18, 3), (32, 16, 3)]
    with pytest.raises(InputError, match="photos have no time"):
        next(photos.frames(FrameSelection(fps=5)))
    single = open_footage(tmp_path / "IMG_2.jpg")
    assert single.info.frame_count == 1 and single.info.focal_35mm == 26.0


def test_photo_folders_that_cannot_be_read(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("x")
    with pytest.raises(InputError, match="holds no photos; expected JPEG or PNG"):
        open_footage(empty)
    heic = tmp_path / "heic"
    heic.mkdir()
    (heic / "IMG_0001.HEIC").write_bytes(b"....ftypheic")
    with pytest.raises(InputError, match="IMG_0001.HEIC: HEIC photos cannot be read"):
        open_footage(heic)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "a.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    with pytest.raises(InputError, match="a.jpg: not a photo that can be read"):
        open_footage(broken)
    cut = tmp_path / "cut"
    cut.mkdir()
    _jpeg(cut / "a.jpg", portrait_frames()[0], 1)
    data = (cut / "a.jpg").read_bytes()
    (cut / "a.jpg").write_bytes(data[: len(data) // 2])  # the header reads, the pixels do not
    photos = open_footage(cut)
    with warnings.catch_warnings(), pytest.raises(InputError, match="a.jpg: the photo cannot be decoded"):
        warnings.simplefilter("ignore")
        list(photos.frames())
