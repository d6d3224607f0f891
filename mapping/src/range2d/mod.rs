//! Terrain maps from 2-D range sensors (paper 003): a tilted laser scanner (Hokuyo
//! URG-04LX) or a laser-stripe camera sweeps a line of terrain ahead of the robot, and the
//! robot's motion sweeps that line over the ground.
//!
//! * [`sensors`]: the stripe sensor (eqs. 1-2, with its uncertainty) and the URG-04LX
//!   (noise, eq. 4's range calibration).
//! * [`plausibility`]: eq. 5's mounting, eq. 7's `gamma`, eqs. 6/8's `Delta z_max`, the
//!   turning extension.
//! * [`certainty`]: the elevation and certainty grids (eqs. 9-11, optional CAS filter).
//! * [`mapper`]: the whole update over a sequence of scans.
//! * [`mixed`]: mixed-measurement removal (range clustering, eq. 12's three-scan analysis).
//! * [`yardstick`]: what a scan map is judged against (naive median, cells seen and swept,
//!   marked mixed returns, object sizes).
//!
//! Scans with their poses are [`stride_core::scan::Scan`]s.

pub mod certainty;
pub mod mapper;
pub mod mixed;
pub mod plausibility;
pub mod sensors;
pub mod yardstick;
