"""A guard around viser's own handler of page values, for the values it cannot cast.

viser (1.1) casts a page's value to the widget's type inside its websocket handler, before any
frhc callback: ``float("abc")`` for a number field, ``float("x")`` for a slider, ``int(nan)``
for an integer slider. The real page never sends these, but a client speaking viser's protocol
may; the cast then raises in a task of viser's event loop, which asyncio reports as a
traceback on the server's stderr ("Task exception was never retrieved"). The widget keeps its
value either way, so nothing reaches the loop; the guard turns the traceback into one line
naming the widget, on stderr and in the sender's page.

It wraps the handler viser registered (``GuiApi._handle_gui_updates`` on the server's websocket
interface): both are viser's private names, so :func:`guard_page_casts` says whether it found
them, and a test holds it to True for the viser this project installs.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Coroutine
from typing import Any

import viser
from viser._messages import GuiUpdateMessage

#: What viser's cast (and its check that a property exists) raises for a value it cannot take.
CAST_ERRORS = (ValueError, TypeError, OverflowError, AssertionError)


def guard_page_casts(server: viser.ViserServer) -> bool:
    """Refuse, in one line, the page values viser's own handler cannot cast (see the module).

    Returns:
        Whether viser's handler was found and wrapped (False: this viser is laid out otherwise,
        and its handler is left as it is).
    """
    interface: Any = getattr(server, "_websock_server", None)
    handler: Callable[[int, GuiUpdateMessage], Coroutine[Any, Any, None]] | None = getattr(
        server.gui, "_handle_gui_updates", None
    )
    handlers = getattr(interface, "_incoming_handlers", {}).get(GuiUpdateMessage, [])
    if handler is None or handler not in handlers:
        return False

    async def guarded(client_id: int, message: GuiUpdateMessage) -> None:
        try:
            await handler(client_id, message)
        except CAST_ERRORS as exc:
            widget = server.gui._gui_input_handle_from_uuid.get(message.uuid)
            label = message.uuid if widget is None else widget.label
            text = f"refused a page value for {label!r}: {message.updates!r} ({type(exc).__name__}: {exc})"
            print(f"frhc web: {text}", file=sys.stderr, flush=True)
            client = server.get_clients().get(client_id)
            if client is not None:
                client.add_notification("Input refused", text, color="red", auto_close_seconds=6.0)

    interface.unregister_handler(GuiUpdateMessage, handler)
    interface.register_handler(GuiUpdateMessage, guarded)
    return True
