"""The servo axis as physics: the compiled kernel (``kernel``), its parameters from an axis
file (``model``), closed-loop simulation (``simulate``) and the independent ``solve_ivp``
reference it is checked against (``reference``)."""
