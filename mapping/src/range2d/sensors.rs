//! The two 2-D range sensors of paper 003 (models in `stride_core::range_sensor`, shared
//! with the simulator): the stripe sensor (eqs. 1-2, its covariance) and the URG-04LX
//! (noise, eq. 4).

pub use stride_core::range_sensor::{StripeNoise, StripeSensor, UrgSensor};
