"""Measurement: closed-loop success (``success``) and its tables, depth realism against real captures
(``realism``, ``paired_depth``), sensor comparisons and the generator's throughput. Nothing here is needed to
train or run a policy; it only measures them."""
