"""What every solver promises, below the solvers (DESIGN section 2): the options vocabulary it takes
(``options``), the Result it returns and how that is measured on the Problem (``result``), and the
optimality measure its status obeys (``optimality``). It imports no solver; ``sagfree.frontend``,
above the solvers, dispatches to them."""
