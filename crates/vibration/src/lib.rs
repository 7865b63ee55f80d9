//! Robot vibration: the modal table, the principal-stiffness two-degree-of-freedom forced
//! response, the suppression bonnet's added damping, and the coupling into removal.
