"""probmap.datasets.ros: ROS 1 (``.bag``) and ROS 2 (``.db3``/``.mcap``) bags, without a ROS
installation.

Bags are read and written through the pure-Python ``rosbags`` package (the ``ros`` extra:
``pip install 'probmap[ros]'``), imported only when a bag is opened: importing this package or
any of its modules does not import ``rosbags``. Four parts, one module each:

- :mod:`~probmap.datasets.ros.tf`: the planar transform tree (:class:`~.tf.TfBuffer`, fed by
  ``tf`` and ``tf_static``) and :func:`~.tf.yaw_from_quaternion`.
- :mod:`~probmap.datasets.ros.summary`: what a bag holds (:func:`~.summary.summarize_bag`, the
  table of ``probmap info BAG``).
- :mod:`~probmap.datasets.ros.scans`: the scan reader (:class:`~.scans.RosBag`,
  :func:`~.scans.load_bag_scans`, :class:`~.scans.RosBagOptions`, :func:`~.scans.is_bag`).
- :mod:`~probmap.datasets.ros.maps`: occupancy grids written to and read from bags
  (:func:`~.maps.write_map_to_bag`, :func:`~.maps.read_map_from_bag`).

``_reader`` holds what they share: the lazy ``rosbags`` import (:func:`~._reader.require_rosbags`,
whose error names the ``ros`` extra), opening a bag and reading and decoding its messages.
"""
