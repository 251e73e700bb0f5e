"""bench/signalk.py's install of the Signal K server: `npm ci` from bench/signalk_server's lockfile, into the cache
once, again when the lockfile changed or an install failed; and the lockfile itself pins every package with its
npm registry URL and hash (without the URLs npm resolves the versions again: docs/marine.md "Signal K").
Node.js and npm are stand-ins here (scripts on PATH that record their calls): no network, no server."""

from __future__ import annotations

import json
import sys

import pytest

from bench.signalk import SERVER_PACKAGE_DIR, SIGNALK_SERVER_VERSION, SignalKUnavailable, ensure_server

# npm ci reads package-lock.json from --prefix; the stand-in records its arguments and that file, then makes the
# server's executable (or not) and exits with FAKE_NPM_EXIT
FAKE_NPM = """#!{python}
import json, os, sys
prefix = sys.argv[sys.argv.index("--prefix") + 1]
with open(os.environ["FAKE_NPM_LOG"], "a") as log:
    log.write(json.dumps({{"args": sys.argv[1:],
                          "lockfile": open(os.path.join(prefix, "package-lock.json")).read(),
                          "package": open(os.path.join(prefix, "package.json")).read()}}) + "\\n")
if os.environ.get("FAKE_NPM_MAKES_BINARY", "1") == "1":
    os.makedirs(os.path.join(prefix, "node_modules", ".bin"), exist_ok=True)
    open(os.path.join(prefix, "node_modules", ".bin", "signalk-server"), "w").close()
sys.exit(int(os.environ.get("FAKE_NPM_EXIT", "0")))
"""
FAKE_NODE = """#!{python}
print("v20.20.2")
"""


@pytest.fixture
def fake_npm(tmp_path, monkeypatch):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, text in (("npm", FAKE_NPM), ("node", FAKE_NODE)):
        (bin_dir / name).write_text(text.format(python=sys.executable))
        (bin_dir / name).chmod(0o755)
    log = tmp_path / "npm-calls.jsonl"
    monkeypatch.setenv("PATH", str(bin_dir))
    monkeypatch.setenv("FAKE_NPM_LOG", str(log))

    def calls():
        return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    return calls


def test_installs_the_lockfile_once_and_again_when_it_changed(tmp_path, fake_npm):
    ours = (SERVER_PACKAGE_DIR / "package-lock.json").read_text()
    cache = tmp_path / "cache"
    binary = ensure_server(cache, log=lambda *_: None)
    assert binary == cache / "node_modules" / ".bin" / "signalk-server"
    (call,) = fake_npm()
    assert call["args"][0] == "ci", call["args"]                 # the lockfile's tree, nothing resolved again
    assert {"--omit=optional", "--ignore-scripts"} <= set(call["args"]), call["args"]
    assert call["lockfile"] == ours
    assert json.loads(call["package"])["dependencies"] == {"signalk-server": SIGNALK_SERVER_VERSION}

    assert ensure_server(cache, log=lambda *_: None) == binary   # installed: npm not run again
    assert len(fake_npm()) == 1

    # a cache an older ahrsd filled (`npm install signalk-server@…`, its own lockfile) is installed again
    (cache / "package-lock.json").write_text(json.dumps({"lockfileVersion": 3, "packages": {}}))
    ensure_server(cache, log=lambda *_: None)
    assert len(fake_npm()) == 2 and fake_npm()[1]["lockfile"] == ours


def test_a_failed_install_is_tried_again(tmp_path, fake_npm, monkeypatch):
    cache = tmp_path / "cache"
    # npm ci failed after it had linked the executable (a download broke off late, say)
    monkeypatch.setenv("FAKE_NPM_EXIT", "1")
    with pytest.raises(SignalKUnavailable, match="npm ci"):
        ensure_server(cache, log=lambda *_: None)
    assert (cache / "node_modules" / ".bin" / "signalk-server").exists()
    monkeypatch.setenv("FAKE_NPM_EXIT", "0")
    ensure_server(cache, log=lambda *_: None)
    assert len(fake_npm()) == 2


def test_the_lockfile_pins_every_package_to_the_registry():
    package = json.loads((SERVER_PACKAGE_DIR / "package.json").read_text())
    lock = json.loads((SERVER_PACKAGE_DIR / "package-lock.json").read_text())
    packages = lock["packages"]
    # npm ci refuses a lockfile out of step with package.json
    assert packages[""]["dependencies"] == package["dependencies"] == {"signalk-server": SIGNALK_SERVER_VERSION}
    assert packages["node_modules/signalk-server"]["version"] == SIGNALK_SERVER_VERSION
    entries = {path: entry for path, entry in packages.items() if path}
    assert len(entries) > 400
    # each package from the npm registry, checked against its hash; an entry without `resolved` (what npm writes
    # with omit-lockfile-registry-resolved, as this machine's ~/.npmrc sets) makes npm ci fetch the version lists
    unpinned = [path for path, entry in entries.items()
                if not entry.get("resolved", "").startswith("https://registry.npmjs.org/")
                or not entry.get("integrity", "").startswith("sha512-")]
    assert unpinned == [], unpinned[:5]
