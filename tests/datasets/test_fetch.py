"""``probmap.datasets.fetch`` and ``probmap datasets fetch`` against a local HTTP server.

Nothing here touches the network: a ``http.server`` on 127.0.0.1 serves a temporary copy of a
few small files of ``shared/data`` (laid out as there), and the fetcher is pointed at it through
its base-URL override (``base_url=`` / ``$PROBMAP_DATA_URL`` / ``--base-url``).
"""

from __future__ import annotations

import hashlib
import shutil
import threading
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.datasets import fetch as F
from probmap.datasets import registry
from probmap.errors import DatasetError

register(app)
runner = CliRunner()

SMALL = F.DATASETS["gtsam-examples"].files  # three files, 22 kB in all
BARCODES = "utias-mrclam/MRCLAM_Dataset7/Barcodes.dat"  # stored upstream with CRLF


class _Handler(SimpleHTTPRequestHandler):
    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        pass


@pytest.fixture
def server(tmp_path, shared_data):
    """A local server of a copy of SMALL and BARCODES: yields (base URL, served folder,
    list of requested paths)."""
    root = tmp_path / "served"
    for place in (*SMALL, BARCODES):
        source = shared_data(place)
        (root / place).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, root / place)
    requests: list[str] = []

    class Handler(_Handler):
        def do_GET(self):
            requests.append(self.path)
            super().do_GET()

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), partial(Handler, directory=str(root)))
    thread = threading.Thread(target=httpd.serve_forever, args=(0.05,), daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/", root, requests
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(5)


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file()) if folder.exists() else []


def test_fetch_downloads_and_verifies(server, tmp_path):
    url, served, requests = server
    out = tmp_path / "data"
    got = F.fetch("gtsam-examples", out, base_url=url)
    assert [f.path for f in got] == [out / p for p in SMALL]
    assert all(f.downloaded for f in got)
    for f, place in zip(got, SMALL, strict=True):
        assert f.url == url + place
        assert f.path.read_bytes() == (served / place).read_bytes()
        assert hashlib.sha256(f.path.read_bytes()).hexdigest() == F.FILES[place].sha256
        assert f.size == f.path.stat().st_size
    assert len(requests) == 3
    assert _files(out) == sorted(out / p for p in SMALL)  # no temporary file left
    import os

    mask = os.umask(0o022)
    os.umask(mask)
    for f in got:  # the mode of every other output, not the 0600 of a private temporary
        assert f.path.stat().st_mode & 0o777 == 0o666 & ~mask


def test_second_fetch_does_not_download(server, tmp_path):
    url, _, requests = server
    out = tmp_path / "data"
    F.fetch("gtsam-examples", out, base_url=url)
    stamps = [(out / p).stat().st_mtime_ns for p in SMALL]
    again = F.fetch("gtsam-examples", out, base_url=url)
    assert not any(f.downloaded for f in again)
    assert len(requests) == 3  # the first fetch's only
    assert [(out / p).stat().st_mtime_ns for p in SMALL] == stamps


def test_a_damaged_local_file_is_downloaded_again(server, tmp_path):
    url, _, requests = server
    out = tmp_path / "data"
    F.fetch("pose-graphs/w100.graph", out, base_url=url)
    (out / "pose-graphs/w100.graph").write_text("damaged")
    (got,) = F.fetch("pose-graphs/w100.graph", out, base_url=url)
    assert got.downloaded and F.sha256_of(got.path) == F.FILES["pose-graphs/w100.graph"].sha256
    assert len(requests) == 2


def test_a_corrupted_file_on_the_server_is_an_error_and_leaves_no_file(server, tmp_path):
    url, served, _ = server
    with open(served / "pose-graphs/w100.graph", "ab") as f:
        f.write(b"# one more line\n")
    actual = hashlib.sha256((served / "pose-graphs/w100.graph").read_bytes()).hexdigest()
    expected = F.FILES["pose-graphs/w100.graph"].sha256
    out = tmp_path / "data"
    with pytest.raises(DatasetError) as info:
        F.fetch("pose-graphs/w100.graph", out, base_url=url)
    msg = str(info.value)
    assert "\n" not in msg
    assert str(out / "pose-graphs/w100.graph") in msg
    assert expected in msg and actual in msg
    assert not out.exists()  # no file, no temporary, not even the folders it made


def test_a_corrupted_file_keeps_the_files_before_it(server, tmp_path):
    url, served, _ = server
    (served / SMALL[-1]).write_text("not the graph")
    out = tmp_path / "data"
    with pytest.raises(DatasetError, match="sha256 mismatch"):
        F.fetch("gtsam-examples", out, base_url=url)
    assert _files(out) == sorted(out / p for p in SMALL[:-1])  # verified ones stay


def test_crlf_files_are_stored_with_lf(server, tmp_path):
    """MRCLAM's mirror stores CRLF line ends; the registry hash is of the LF file."""
    url, served, _ = server
    path = served / BARCODES
    path.write_bytes(path.read_bytes().replace(b"\n", b"\r\n"))
    (got,) = F.fetch(BARCODES, tmp_path / "data", base_url=url)
    assert b"\r" not in got.path.read_bytes()
    assert F.sha256_of(got.path) == F.FILES[BARCODES].sha256


def test_environment_overrides(server, tmp_path, monkeypatch):
    url, _, requests = server
    monkeypatch.setenv("PROBMAP_DATA_URL", url)
    monkeypatch.setenv("PROBMAP_DATA", str(tmp_path / "env-data"))
    (got,) = F.fetch("pose-graphs/pose2example.txt")
    assert got.path == tmp_path / "env-data" / "pose-graphs/pose2example.txt"
    assert got.url == url + "pose-graphs/pose2example.txt" and requests


def test_unknown_name_is_one_line_listing_the_known_names():
    with pytest.raises(ValueError) as info:
        F.files_of("intel-raw")
    msg = str(info.value)
    assert "\n" not in msg and "'intel-raw'" in msg
    for name in F.DATASETS:
        assert name in msg


def test_an_unreachable_server_is_one_line_and_leaves_no_file(tmp_path):
    import socket

    with socket.socket() as s:  # a port that nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "data"
    with pytest.raises(ConnectionError) as info:
        F.fetch("pose-graphs/w100.graph", out, base_url=f"http://127.0.0.1:{port}")
    assert f"127.0.0.1:{port}/pose-graphs/w100.graph" in str(info.value)
    assert not out.exists()


def test_default_directory(monkeypatch, tmp_path):
    import pooch

    monkeypatch.delenv("PROBMAP_DATA", raising=False)
    assert F.default_directory() == Path(pooch.os_cache("probmap"))
    monkeypatch.setenv("PROBMAP_DATA", str(tmp_path))
    assert F.default_directory() == tmp_path
    assert F.default_directory(tmp_path / "x") == tmp_path / "x"


def test_public_addresses_are_pinned_to_a_commit(monkeypatch):
    monkeypatch.delenv("PROBMAP_DATA_URL", raising=False)
    for place, entry in F.FILES.items():
        assert entry.path == place
        url = F.file_url(entry)
        assert url == f"https://github.com/{entry.repo}/raw/{entry.commit}/{entry.source_path}"
        assert len(entry.commit) in (8, 40) and int(entry.commit, 16) >= 0
        assert len(entry.sha256) == 64 and int(entry.sha256, 16) >= 0
    assert [p for p in F.FILES if F.FILES[p].strip_cr] == [
        p for p in F.FILES if p.startswith("utias-mrclam/")
    ]


def test_every_dataset_name_is_covered():
    """Every fetch name lists files of the registry; every registered dataset with a path
    (``probmap.datasets.registry``) is made present by the fetch name of the same name."""
    for d in F.DATASETS.values():
        assert d.files and all(p in F.FILES for p in d.files)
    assert set(F.DATASETS["all"].files) == set(F.FILES)
    for info in registry.DATASETS.values():
        if info.relpath is None:
            continue
        files = F.DATASETS[info.name].files
        assert any(p == info.relpath or p.startswith(info.relpath + "/") for p in files), info


def test_registry_hashes_match_shared_data(shared_data):
    for place, entry in F.FILES.items():
        assert F.sha256_of(shared_data(place)) == entry.sha256, place


# ------------------------------------------------------------------------------ the CLI
def test_cli_fetch(server, tmp_path):
    url, served, _ = server
    out = tmp_path / "data"
    args = ["datasets", "fetch", "gtsam-examples", "--dir", str(out), "--base-url", url]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    for place in SMALL:
        assert any(line.startswith("downloaded") and line.endswith(place) for line in lines)
    assert f"3 files in {out}, sha256 checked (3 downloaded, 0 already present)" in res.output
    assert f"export PROBMAP_DATA={out}" in res.output

    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "(0 downloaded, 3 already present)" in res.output
    assert sum(line.startswith("present") for line in res.output.splitlines()) == 3

    (served / "pose-graphs/w100.graph").write_text("tampered")
    res = runner.invoke(app, [*args[:2], "pose-graphs/w100.graph", *args[3:]])
    assert res.exit_code == 0, res.output  # present with the right hash: the server is not asked
    (out / "pose-graphs/w100.graph").unlink()
    res = runner.invoke(app, [*args[:2], "pose-graphs/w100.graph", *args[3:]])
    assert res.exit_code == 1
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert "sha256 mismatch" in lines[0] and str(out / "pose-graphs/w100.graph") in lines[0]
    assert not (out / "pose-graphs/w100.graph").exists()


def test_cli_fetch_into_a_relative_folder(server, tmp_path, monkeypatch):
    url, _, _ = server
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(
        app, ["datasets", "fetch", "pose-graphs/w100.graph", "--dir", "rel", "--base-url", url]
    )
    assert res.exit_code == 0, res.output
    assert "pose-graphs/w100.graph" in res.output and f"1 file in {tmp_path / 'rel'}" in res.output
    assert (tmp_path / "rel/pose-graphs/w100.graph").is_file()


def test_cli_unknown_name_downloads_nothing(server, tmp_path):
    url, _, requests = server
    out = tmp_path / "data"
    res = runner.invoke(
        app, ["datasets", "fetch", "gtsam-examples", "nope", "--dir", str(out), "--base-url", url]
    )
    assert res.exit_code == 1
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: unknown dataset 'nope'"), res.output
    assert "mrclam7" in lines[0] and not requests and not out.exists()


def test_cli_list(tmp_path):
    res = runner.invoke(app, ["datasets", "list", "--data-dir", str(tmp_path)])
    assert res.exit_code == 0, res.output
    for name in ("victoria-park", "mrclam7", "gtsam-examples", "pose-graphs", "simulation"):
        assert name in res.output
    assert "probmap datasets fetch NAME" in res.output
