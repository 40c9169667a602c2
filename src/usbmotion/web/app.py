"""The dashboard served over HTTP and a WebSocket (Starlette), as ``docs/dashboard.md`` says.

Every ``/api/`` call needs the token (``Authorization: Bearer`` or ``?token=``): a browser
can move the machine, and any page a browser shows could otherwise reach a local port. The
page itself (``static/``) needs none: it holds nothing of the machine and reads the token
from its address.

The WebSocket pushes the live model :data:`PUSH_HZ` times a second, each push with every
axis's peak following error since the push before (a reader of its own), and every message
as it comes. A client that goes away changes nothing on the machine.
"""

from __future__ import annotations

import asyncio
import json
import secrets
import time
from collections.abc import Awaitable, Callable
from importlib import resources
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect

from usbmotion.web.dashboard import UPLOAD_LIMIT_BYTES, Dashboard, Message, RefusedError

PUSH_HZ = 60.0
"""Pushes a second on the WebSocket: at least 50 with room for a late one."""
POLICY_VIOLATION = 1008
"""The WebSocket close code for a missing or wrong token."""


def static_folder() -> Path:
    """The page's files (``index.html``, ``style.css`` and the bundle in ``dist/``)."""
    return Path(str(resources.files("usbmotion") / "web" / "static"))


def page_built() -> bool:
    """Whether the page's bundle is there (``make web`` builds it)."""
    return (static_folder() / "dist" / "app.js").is_file()


def new_token() -> str:
    """A token for a session: 128 random bits, URL-safe."""
    return secrets.token_urlsafe(16)


class _TokenGate:
    """Refuses ``/api/`` requests without the token (401), WebSockets with 1008."""

    def __init__(self, app: ASGIApp, token: str) -> None:
        self.app = app
        self.token = token

    def _given(self, scope: Scope) -> str:
        for key, value in scope.get("headers", []):
            if key == b"authorization":
                text = str(value.decode("latin-1"))
                if text.lower().startswith("bearer "):
                    return text[7:].strip()
        query = str(scope.get("query_string", b"").decode("latin-1"))
        for pair in query.split("&"):
            name, _, given = pair.partition("=")
            if name == "token":
                return given
        return ""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "")
        if scope["type"] in ("http", "websocket") and path.startswith("/api"):
            given = self._given(scope)
            if not secrets.compare_digest(given.encode(), self.token.encode()):
                why = ("the token is missing: give it as Authorization: Bearer TOKEN or"
                       " ?token=TOKEN (usbmotion web printed it)" if not given
                       else "the token is wrong (usbmotion web printed the right one)")
                if scope["type"] == "websocket":
                    await send({"type": "websocket.close", "code": POLICY_VIOLATION,
                                "reason": why[:120]})
                    return
                response = JSONResponse({"error": why}, status_code=401,
                                        headers={"WWW-Authenticate": "Bearer"})
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


async def _body(request: Request) -> dict[str, Any]:
    raw = await request.body()
    if not raw.strip():
        return {}
    try:
        value = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        raise RefusedError(400, "the body is not JSON") from None
    if not isinstance(value, dict):
        raise RefusedError(400, "the body is not a JSON object")
    return value


def _message_json(message: Message) -> dict[str, Any]:
    return {"type": "message", "sequence": message.sequence, "level": message.level,
            "text": message.text}


Handler = Callable[[Request], Awaitable[Any]]


def _api(handler: Handler) -> Callable[[Request], Awaitable[Response]]:
    """An endpoint: its result as JSON (``{"ok": true}`` for None), a refusal as its
    status and ``{"error": ...}``."""

    async def endpoint(request: Request) -> Response:
        try:
            result = await handler(request)
        except RefusedError as refusal:
            return _error(refusal.status, refusal.message)
        return JSONResponse({"ok": True} if result is None else result)

    return endpoint


def create_app(dashboard: Dashboard, *, token: str) -> ASGIApp:
    """The dashboard's web application, behind its token gate."""
    state_reader = dashboard.reader()

    def work(action: Callable[[], Any]) -> Awaitable[Any]:
        return run_in_threadpool(action)

    async def state(request: Request) -> Any:
        return dashboard.state(state_reader)

    async def program(request: Request) -> Any:
        return dashboard.program_view()

    async def programs(request: Request) -> Any:
        return dashboard.catalogue()

    async def report(request: Request) -> Any:
        return dashboard.report()

    async def messages(request: Request) -> Any:
        try:
            after = int(request.query_params.get("after", "0"))
        except ValueError:
            raise RefusedError(400, "after: a message sequence number") from None
        return {"messages": [_message_json(m) for m in dashboard.messages(after)]}

    async def upload(request: Request) -> Any:
        name = request.query_params.get("name", "")
        declared = request.headers.get("content-length")
        if declared is not None and declared.isdigit() and int(declared) > UPLOAD_LIMIT_BYTES:
            raise RefusedError(413, f"program {name!r} is {int(declared):,} bytes: at most"
                                    f" {UPLOAD_LIMIT_BYTES:,} bytes may be uploaded")
        body = bytearray()
        async for chunk in request.stream():
            body += chunk
            if len(body) > UPLOAD_LIMIT_BYTES:
                raise RefusedError(413, f"program {name!r} is over {UPLOAD_LIMIT_BYTES:,}"
                                        " bytes: at most that may be uploaded")
        return await work(lambda: dashboard.upload(name, bytes(body)))

    async def open_program(request: Request) -> Any:
        body = await _body(request)
        if "demo" in body:
            return await work(lambda: dashboard.open_demo(body["demo"]))
        if "file" in body:
            file = body["file"]
            if not isinstance(file, str):
                raise RefusedError(400, f"file {file!r}: a file name")
            return await work(lambda: dashboard.open_file(file))
        raise RefusedError(400, "open: give {\"file\": NAME} or {\"demo\": NUMBER}")

    def simple(action: Callable[[], Any]) -> Handler:
        async def handler(request: Request) -> Any:
            await _body(request)
            return await work(action)
        return handler

    async def run(request: Request) -> Any:
        body = await _body(request)
        return await work(lambda: dashboard.run(body.get("from_line")))

    async def predict(request: Request) -> Any:
        body = await _body(request)
        unknown = sorted(set(body) - {"tolerance_mm", "from_line"})
        if unknown:
            raise RefusedError(422, f"predict: unknown key {unknown[0]!r}: allowed"
                                    " tolerance_mm, from_line")
        return await work(lambda: dashboard.predict(body.get("tolerance_mm"),
                                                    body.get("from_line")))

    async def home(request: Request) -> Any:
        body = await _body(request)
        return await work(lambda: dashboard.home(body.get("axes")))

    async def jog(request: Request) -> Any:
        body = await _body(request)
        continuous = body.get("continuous", False)
        if not isinstance(continuous, bool):
            raise RefusedError(400, f"continuous {continuous!r}: true or false")
        return await work(lambda: dashboard.jog(body.get("moves"),  # type: ignore[arg-type]
                                                feed_mm_min=body.get("feed_mm_min"),
                                                continuous=continuous))

    async def mdi(request: Request) -> Any:
        body = await _body(request)
        return await work(lambda: dashboard.mdi(body.get("line")))

    async def overrides(request: Request) -> Any:
        body = await _body(request)
        return await work(lambda: dashboard.overrides(feed=body.get("feed"),
                                                      rapid=body.get("rapid")))

    async def zero(request: Request) -> Any:
        body = await _body(request)
        origin = await work(lambda: dashboard.zero(body.get("axes"),
                                                   system=body.get("system", 1)))
        return {"ok": True, "origin_mm": origin}

    async def select_system(request: Request) -> Any:
        body = await _body(request)
        return await work(lambda: dashboard.select_system(body.get("system")))

    async def devices(request: Request) -> Any:
        return await work(dashboard.devices)

    async def set_parameter(request: Request) -> Any:
        body = await _body(request)
        axis = request.path_params["axis"]
        return await work(lambda: dashboard.set_parameter(
            axis, body.get("name"), body.get("value"), flash=body.get("flash", False)))

    async def tune(request: Request) -> Any:
        body = await _body(request)
        return await work(lambda: dashboard.tune(body.get("axis"),
                                                 step_mm=body.get("step_mm", 1.0)))

    async def measure_tool(request: Request) -> Any:
        body = await _body(request)
        return await work(lambda: dashboard.measure_tool(body.get("tool")))

    async def tune_auto(request: Request) -> Any:
        body = await _body(request)
        return await work(lambda: dashboard.tune_auto(
            body.get("axis"), travel_mm=body.get("travel_mm"), write=body.get("write", False)))

    async def live(socket: WebSocket) -> None:
        await socket.accept()
        reader = dashboard.reader()
        period = 1.0 / PUSH_HZ
        sent = 0
        for message in dashboard.messages():
            await socket.send_text(json.dumps(_message_json(message)))
            sent = message.sequence
        listening = asyncio.create_task(_until_closed(socket))
        due = time.monotonic()
        try:
            while not listening.done():
                await socket.send_text(json.dumps(dashboard.state(reader)))
                if dashboard.message_sequence != sent:
                    for message in dashboard.messages(sent):
                        await socket.send_text(json.dumps(_message_json(message)))
                        sent = message.sequence
                due = max(due + period, time.monotonic() - period)
                await asyncio.wait({listening}, timeout=max(0.0, due - time.monotonic()))
        except (WebSocketDisconnect, RuntimeError, OSError):
            pass  # the page went away; the machine goes on
        finally:
            listening.cancel()

    routes = [
        Route("/api/state", _api(state)),
        Route("/api/program", _api(program)),
        Route("/api/programs", _api(programs)),
        Route("/api/messages", _api(messages)),
        Route("/api/report", _api(report)),
        Route("/api/program/upload", _api(upload), methods=["POST"]),
        Route("/api/program/open", _api(open_program), methods=["POST"]),
        Route("/api/run", _api(run), methods=["POST"]),
        Route("/api/predict", _api(predict), methods=["POST"]),
        Route("/api/hold", _api(simple(dashboard.hold)), methods=["POST"]),
        Route("/api/resume", _api(simple(dashboard.resume)), methods=["POST"]),
        Route("/api/stop", _api(simple(dashboard.stop)), methods=["POST"]),
        Route("/api/reset", _api(simple(dashboard.reset)), methods=["POST"]),
        Route("/api/home", _api(home), methods=["POST"]),
        Route("/api/jog", _api(jog), methods=["POST"]),
        Route("/api/jog/cancel", _api(simple(dashboard.jog_cancel)), methods=["POST"]),
        Route("/api/mdi", _api(mdi), methods=["POST"]),
        Route("/api/overrides", _api(overrides), methods=["POST"]),
        Route("/api/offsets/zero", _api(zero), methods=["POST"]),
        Route("/api/offsets/select", _api(select_system), methods=["POST"]),
        Route("/api/devices", _api(devices)),
        Route("/api/devices/{axis}/parameters", _api(set_parameter), methods=["POST"]),
        Route("/api/tune", _api(tune), methods=["POST"]),
        Route("/api/tune/auto", _api(tune_auto), methods=["POST"]),
        Route("/api/tool/measure", _api(measure_tool), methods=["POST"]),
        WebSocketRoute("/api/live", live),
        Mount("/", StaticFiles(directory=static_folder(), html=True, check_dir=False)),
    ]
    return _TokenGate(Starlette(routes=routes), token)


async def _until_closed(socket: WebSocket) -> None:
    """Returns once the client closes (what it sends is not used)."""
    while True:
        message = await socket.receive()
        if message["type"] == "websocket.disconnect":
            return
