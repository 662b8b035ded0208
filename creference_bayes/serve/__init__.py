"""``creference serve``: a Label Studio ML backend that shows each frame's estimate in the
annotation tool (docs/serve.md).

- :mod:`.predictions`: a task → its frame's scene → the estimate as a Label Studio prediction (no web
  framework);
- :mod:`.jobs`: the service's folder (tasks, results, advice; nothing lost on a restart) and the
  background queue that samples each frame's posterior and finds its next request;
- :mod:`.app`: the Flask app answering Label Studio's ML backend protocol (``/health``, ``/setup``,
  ``/predict``, ``/webhook``), with a token, a body size limit and a 4xx for every body it cannot use.

Flask is the optional extra ``[serve]``; only :mod:`.app` imports it.
"""

from .predictions import RequestError, serve_config

__all__ = ["RequestError", "serve_config"]
