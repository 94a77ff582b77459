"""The MJPEG fan-out: the producer (the ROS callback) never waits; each client gets the newest frame."""

import io
import threading
import time

from espdock_demo.mjpeg import BOUNDARY, FrameBroadcaster, jpeg_size, multipart_chunk


def test_a_client_gets_the_newest_frame_and_skips_the_rest():
    frames = FrameBroadcaster()
    for i in range(5):
        frames.publish(b"frame%d" % i)
    got = frames.wait_newer(0, timeout=0.1)
    assert got.data == b"frame4" and got.seq == 5
    assert frames.wait_newer(got.seq, timeout=0.05) is None


def test_a_waiting_client_wakes_on_the_next_frame():
    frames = FrameBroadcaster()
    results = []
    waiter = threading.Thread(target=lambda: results.append(frames.wait_newer(0, timeout=5)))
    waiter.start()
    time.sleep(0.05)
    frames.publish(b"x")
    waiter.join(2)
    assert results and results[0].data == b"x"


def test_publishing_never_waits_for_slow_clients():
    """Clients that hold a frame for a long time (a slow socket) cost the producer nothing."""
    frames = FrameBroadcaster()
    stop = threading.Event()
    received = {i: 0 for i in range(8)}

    def client(i):
        seq = 0
        while not stop.is_set():
            frame = frames.wait_newer(seq, timeout=0.2)
            if frame:
                seq = frame.seq
                received[i] += 1
                time.sleep(0.05 if i < 4 else 0.001)  # half of them are slow

    threads = [threading.Thread(target=client, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    worst = 0.0
    for i in range(300):
        begin = time.perf_counter()
        frames.publish(b"%d" % i)
        worst = max(worst, time.perf_counter() - begin)
        time.sleep(0.002)
    stop.set()
    frames.close()
    for t in threads:
        t.join(2)
    assert worst < 0.02, f"publish took {worst * 1000:.1f} ms"
    assert all(received[i] > 0 for i in received)
    assert min(received[i] for i in range(4, 8)) > 2 * max(received[i] for i in range(4))


def test_close_wakes_every_client():
    frames = FrameBroadcaster()
    results = []
    t = threading.Thread(target=lambda: results.append(frames.wait_newer(0, timeout=10)))
    t.start()
    time.sleep(0.05)
    frames.close()
    t.join(2)
    assert results == [None]


def test_age_and_rate_follow_the_clock():
    now = [100.0]
    frames = FrameBroadcaster(clock=lambda: now[0])
    assert frames.age() is None and frames.rate() == 0
    for _ in range(60):
        frames.publish(b"x")
        now[0] += 1 / 30
    assert frames.rate(window=2.0) == 30
    now[0] += 5
    assert frames.age() > 5 and frames.rate() == 0


def test_a_multipart_chunk_carries_its_length():
    chunk = multipart_chunk(b"\xff\xd8abc")
    assert chunk.startswith(f"--{BOUNDARY}\r\n".encode())
    assert b"Content-Length: 5\r\n\r\n\xff\xd8abc\r\n" in chunk


def test_jpeg_size_reads_the_frame_header():
    from demo_unit_support import require

    require("PIL")
    from PIL import Image

    for size in ((320, 240), (1600, 1200), (96, 96)):
        out = io.BytesIO()
        Image.new("RGB", size).save(out, "JPEG")
        assert jpeg_size(out.getvalue()) == size
    out = io.BytesIO()
    Image.new("RGB", (640, 480)).save(out, "JPEG", progressive=True)
    assert jpeg_size(out.getvalue()) == (640, 480)


def test_jpeg_size_of_junk_is_none():
    for junk in (b"", b"\xff\xd8", b"\xff\xd8\xff\xe0\x00\x10garbage", b"GIF89a", b"\xff\xd8\x00\x00\x00\x00"):
        assert jpeg_size(junk) is None
