"""Design search: from a specification to lenses, beyond the nearest local minimum.

``spec`` (what is asked), ``start`` (thin-lens and flat starting points), ``problem`` (the
merit, variables and constraints of a spec on a lens), ``refine`` (one local refinement:
semi-diameters fitted to the beam, damped least squares, curriculum), ``multistart`` (the
global strategy: quasi-random starts, de-duplication, basin hopping, the best k designs),
``result`` (evaluation and files).  Glass substitution plugs in through ``glass_strategy``.
"""

from .multistart import Design, SearchConfig, SearchResult, search
from .refine import Stage
from .result import evaluate, write_outputs
from .spec import DesignSpec, SpecError
from .start import StartError, flat_start, solve_efl, thin_lens_start

__all__ = ["DesignSpec", "SpecError", "SearchConfig", "SearchResult", "Design", "search",
           "Stage", "evaluate", "write_outputs", "thin_lens_start", "flat_start",
           "solve_efl", "StartError"]
