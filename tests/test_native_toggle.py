"""numpy_only() / set_enabled() in one thread never switch paths inside another thread's decode
(issue 19 item 8: "'RansDecoder' object has no attribute '_nt'")."""
import threading
import time

import pytest

from gsz.decoder import decode, native
from codec_util import encoded


@pytest.mark.skipif(not native.native_available(), reason="native accelerator not built")
def test_decodes_in_threads_survive_path_toggles_in_other_threads():
    data = encoded("sh3", 400, bits=8, codebook=32).data
    with native.numpy_only():
        want = decode(data)
    errors, done = [], []
    stop = threading.Event()

    def decoder(numpy_only: bool):
        while not stop.is_set():
            try:
                if numpy_only:
                    with native.numpy_only():
                        assert native.active_path() == "numpy"
                        got = decode(data)
                else:
                    got = decode(data)
                assert got.equals(want)
                done.append(1)
            except BaseException as e:         # reported on the test's thread
                errors.append(e)
                stop.set()

    threads = [threading.Thread(target=decoder, args=(k == 2,), daemon=True) for k in range(3)]
    for t in threads:
        t.start()
    old = native.set_enabled(True)
    try:
        t0 = time.perf_counter()
        flips = 0
        while time.perf_counter() - t0 < 3 and not stop.is_set():
            native.set_enabled(flips % 2 == 0)       # process-wide toggles, as fast as they come
            flips += 1
            time.sleep(0.0002)
    finally:
        stop.set()
        for t in threads:
            t.join(30)
        native.set_enabled(old)
    assert not errors, repr(errors[0])
    assert len(done) >= 6 and flips > 100


def test_numpy_only_is_per_thread():
    seen = {}
    inside = threading.Event()
    leave = threading.Event()

    def other():
        with native.numpy_only():
            seen["inner"] = native.active_path()
            inside.set()
            leave.wait(10)

    t = threading.Thread(target=other)
    t.start()
    inside.wait(10)
    try:
        seen["outer"] = native.active_path()
    finally:
        leave.set()
        t.join(10)
    assert seen["inner"] == "numpy"
    assert seen["outer"] == ("native" if native.enabled() else "numpy")
