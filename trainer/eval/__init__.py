"""Measurement, kept apart from what it measures: closed-loop success (``success``) and its comparison tables
(``table``), depth realism against real captures (``realism``, ``paired_depth``), what each sensor model takes
from the policy's view (``sensor_compare``) and the generator's throughput (``ddg_throughput``). The
generator, the simulator and the policies never import it; the ``ddg`` menu offers its DDG measurements and
the student recipe reports its rounds with ``success``."""
