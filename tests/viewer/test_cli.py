"""`dyngi view` input errors: one line on the command line (exit 2), nothing served."""
import socket

import pytest

from dyngi.cli import main


@pytest.mark.parametrize("argv, needle", [
    (["view", "no-such-scene"], "unknown scene 'no-such-scene'"),
    (["view", "cornell-static", "--techniques", "nope"], "unknown technique 'nope'"),
    (["view", "cornell-static", "--techniques", "ddgi:hysteresis=2"], "hysteresis"),
    (["view", "cornell-static", "--techniques", "ddgi:bogus=1"], "unknown parameter 'bogus'"),
    (["view", "cornell-static", "--res", "0x9"], "resolution '0x9'"),
])
def test_bad_input_is_one_line(backend, capsys, argv, needle):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err
    assert err.startswith("dyngi: error: ") and err.count("\n") == 1 and "Traceback" not in err


def test_busy_port_is_one_line(backend, capsys):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(1)
    port = s.getsockname()[1]
    try:
        rc = main(["view", "cornell-static", "--techniques", "path:spp=1", "--res", "16x9", "--port", str(port)])
    finally:
        s.close()
    err = capsys.readouterr().err
    assert rc == 2, err
    assert f"port {port}" in err and "--port" in err and err.count("\n") == 1


def test_port_out_of_range_is_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        main(["view", "cornell-static", "--port", "99999"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "0..65535" in err and err.count("\n") == 1
