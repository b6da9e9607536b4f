"""The ROS 2 ``rosidl_adapter`` interface parser, vendored (Apache-2.0; see ``NOTICE``).

Only :mod:`toolkit.vendor.rosidl_adapter.parser` is included: ``parse_message_string`` and the
``MessageSpecification`` tree it returns. :mod:`toolkit.mcapio.msgdefs` wraps it; use that.
"""
