"""No web page can drive the inspector (issue 13, point 1): foreign Origin, wrong Host, missing
or wrong token are refused before any viser message, by a raw WebSocket client and over HTTP."""

from __future__ import annotations

import http.client
from collections.abc import Iterator

import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from hdrview.app import InspectorApp, create_app
from hdrview.guard import ConnectionGuard

from ._brackets import write_png_bracket


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[InspectorApp]:
    root = tmp_path_factory.mktemp("guard")
    write_png_bracket(root / "b")
    a = create_app(
        [str(root / "b")],
        port=0,
        root=str(root),
        verbose=False,
        demo_dir=None,
        allow_origins=["https://proxy.example:8443"],
    )
    try:
        yield a
    finally:
        a.stop()
        a.server.stop()


def _ws(
    app: InspectorApp,
    *,
    origin: str | None = None,
    host: str | None = None,
    token: str | None = "good",
) -> None:
    port = app.server.get_port()
    assert app.guard is not None
    t = app.guard.token if token == "good" else token
    url = f"ws://127.0.0.1:{port}/" + ("" if t is None else f"?token={t}")
    headers = {}
    if host is not None:
        headers["Host"] = host
    with connect(
        url, origin=origin, additional_headers=headers, subprotocols=["viser-v1"], open_timeout=5
    ) as ws:
        ws.close()


def _http(app: InspectorApp, path: str, headers: dict[str, str]) -> tuple[int, str, str]:
    conn = http.client.HTTPConnection("127.0.0.1", app.server.get_port(), timeout=5)
    conn.request("GET", path, headers=headers)
    r = conn.getresponse()
    body = r.read().decode("utf-8", "replace")
    return r.status, body, r.getheader("Set-Cookie") or ""


def test_the_printed_address_works(app):
    port = app.server.get_port()
    assert app.url == f"http://127.0.0.1:{port}/?token={app.guard.token}"
    _ws(app, origin=f"http://127.0.0.1:{port}")
    _ws(app, origin=f"http://localhost:{port}")
    _ws(app, origin="https://proxy.example:8443")  # --allow-origin
    status, _, cookie = _http(app, f"/?token={app.guard.token}", {})
    assert status == 200 and "hdrview_token=" in cookie and "SameSite=Strict" in cookie


@pytest.mark.parametrize(
    "origin", ["http://evil.example", "http://127.0.0.1:1", "null", "https://proxy.example:9999"]
)
def test_foreign_origin_is_refused(app, origin):
    with pytest.raises(InvalidStatus) as err:
        _ws(app, origin=origin)
    assert err.value.response.status_code == 403
    assert b"Origin" in err.value.response.body


@pytest.mark.parametrize("host", ["evil.example", "evil.example:{port}", "127.0.0.1:1"])
def test_wrong_host_is_refused(app, host):
    """DNS rebinding: a name that resolves to 127.0.0.1 still sends its own Host."""
    with pytest.raises(InvalidStatus) as err:
        _ws(app, host=host.format(port=app.server.get_port()))
    assert err.value.response.status_code == 403
    status, body, _ = _http(
        app, f"/?token={app.guard.token}", {"Host": host.format(port=app.server.get_port())}
    )
    assert status == 403 and "Host" in body


@pytest.mark.parametrize("token", [None, "wrong", ""])
def test_missing_or_wrong_token_is_refused(app, token):
    with pytest.raises(InvalidStatus) as err:
        _ws(app, origin=f"http://127.0.0.1:{app.server.get_port()}", token=token)
    assert err.value.response.status_code == 403
    status, body, _ = _http(app, "/" if token is None else f"/?token={token}", {})
    assert status == 403 and "token" in body


def test_cookie_carries_the_token_for_the_page_assets(app):
    status, _, _ = _http(app, "/", {"Cookie": f"hdrview_token={app.guard.token}"})
    assert status == 200


def test_no_token_mode_keeps_the_address_checks():
    g = ConnectionGuard(lambda: 8080, token=None)
    assert g.refusal("/", {"Host": "127.0.0.1:8080"}) is None
    assert "Origin" in g.refusal("/", {"Host": "127.0.0.1:8080", "Origin": "http://evil.example"})
    assert "Host" in g.refusal("/", {"Host": "evil.example:8080"})
    assert g.url() == "http://127.0.0.1:8080/"
