//! Independent high-accuracy reference solutions: the ψ-eliminated ODE
//! integrated by a high-order extrapolation method (to be written).
