"""The closed loop: one controller protocol and one engine (:mod:`lpvflow.loop.protocol`,
:mod:`lpvflow.loop.engine`)."""
