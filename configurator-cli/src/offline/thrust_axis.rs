//! `solve thrust-axis`: see the module docs once written.
