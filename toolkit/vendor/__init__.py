"""Third-party code the toolkit ships a copy of, each package with its licence and a NOTICE.

Code lands here when the toolkit needs it but cannot rely on it where it lives (for example
when the only installable copy sits in another library's private module). Each package keeps
its upstream licence file and a ``NOTICE`` naming its origin, version and any change made.

- :mod:`toolkit.vendor.rosidl_adapter`: the ROS 2 ``.msg`` parser (Apache-2.0).
"""
