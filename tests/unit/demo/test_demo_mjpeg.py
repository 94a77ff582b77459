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
    """Clients that hold a frame (a stuck socket) cost the producer nothing: it publishes every
    frame while they still hold their first one. (How fast a publish is, is the demo benchmark's:
    a wall-clock bound here failed on a loaded machine, 20.5 ms against 20.)"""
    frames = FrameBroadcaster()
    stop, release = threading.Event(), threading.Event()
    received = {i: 0 for i in range(8)}

    def client(i):
        seq = 0
        while not stop.is_set():
            frame = frames.wait_newer(seq, timeout=0.2)
            if frame:
                seq = frame.seq
                received[i] += 1
                if i < 4:
                    release.wait()  # half of them are stuck until the producer is done
                else:
                    time.sleep(0.001)

    threads = [threading.Thread(target=client, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()

    def produce():
        for i in range(300):
            frames.publish(b"%d" % i)
            time.sleep(0.002)

    producer = threading.Thread(target=produce)
    producer.start()
    producer.join(30)
    done = not producer.is_alive()
    held = [received[i] for i in range(4)]
    release.set()
    stop.set()
    frames.close()
    for t in [*threads, producer]:
        t.join(2)
    assert done, "publish waited for the clients that hold a frame"
    assert held == [1, 1, 1, 1], held
    assert all(received[i] > 2 * max(held) for i in range(4, 8)), received


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
