"""Detection metrics of each dataset's own protocol, one module per protocol (``waymo``)."""
