//! Navigation: reachable positions on a 0.25 m grid, geodesic (shortest-path) distances to a
//! target's success region, and the expert (shortest-path) next action.
//!
//! The robot itself moves off the grid (15° turns, 0.25 m steps), so distances at a continuous
//! position are read from the nearby grid points plus the straight offset to them.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use nalgebra::{Point2, Point3, Vector2};

use crate::camera::{Camera, Intrinsics};
use crate::geometry::{angle_diff_deg, heading, xz};
use crate::physics::Physics;
use crate::robot::{Action, RobotPose};
use crate::scene::Room;
use crate::visibility;
use farm::config::EnvConfig;

/// Grid spacing (metres): AI2-THOR's and the dissertation's.
pub const GRID_STEP: f32 = 0.25;

/// Reachable grid points of a room. Points are at integer multiples of the step, so that
/// positions written by hand ("x": 1.25) fall on the grid.
#[derive(Clone, Debug)]
pub struct NavGrid {
    pub step: f32,
    /// Grid index of column 0 / row 0: x = (i0 + col) * step, z = (k0 + row) * step.
    i0: i32,
    k0: i32,
    pub nx: usize,
    pub nz: usize,
    /// The robot fits here.
    free: Vec<bool>,
    /// Per grid square, by its lower-left point: whether the robot may be somewhere inside
    /// (a superset of where it can be, for SPL's lower bound; see [`NavGrid::build`]).
    passable: Vec<bool>,
}

/// Sub-squares per side tested for a passable grid square.
const PASSABLE_SUBDIVISIONS: usize = 4;

/// A cell index into the grid.
pub type Cell = usize;

impl NavGrid {
    /// Tests every grid point of the room for the robot's capsule.
    pub fn build(physics: &Physics, room: &Room, step: f32) -> NavGrid {
        let (hx, hz) = room.half();
        let i0 = (-hx / step).ceil() as i32;
        let i1 = (hx / step).floor() as i32;
        let k0 = (-hz / step).ceil() as i32;
        let k1 = (hz / step).floor() as i32;
        let nx = (i1 - i0 + 1).max(0) as usize;
        let nz = (k1 - k0 + 1).max(0) as usize;
        let mut g = NavGrid { step, i0, k0, nx, nz, free: vec![false; nx * nz], passable: vec![false; nx * nz] };
        for c in 0..nx * nz {
            g.free[c] = physics.robot_fits(g.point(c));
        }
        // Wherever the robot fits inside a square, a robot thinner by a sub-square's
        // half-diagonal fits at the nearest sub-square centre. So no position the robot can
        // reach lies outside the passable squares, even in a gap too narrow for any grid point.
        let sub = step / PASSABLE_SUBDIVISIONS as f32;
        let slack = sub * std::f32::consts::FRAC_1_SQRT_2;
        g.mark_passable(|g, c| {
            (0..PASSABLE_SUBDIVISIONS * PASSABLE_SUBDIVISIONS).any(|i| {
                let (u, v) = ((i % PASSABLE_SUBDIVISIONS) as f32 + 0.5, (i / PASSABLE_SUBDIVISIONS) as f32 + 0.5);
                physics.thinner_robot_fits(g.point(c) + Vector2::new(u * sub, v * sub), slack)
            })
        });
        g
    }

    /// Marks a square passable where the robot fits at one of its corners, or where `inside`
    /// says it fits somewhere within.
    fn mark_passable(&mut self, inside: impl Fn(&NavGrid, Cell) -> bool) {
        for c in self.squares() {
            self.passable[c] = self.square_corners(c).iter().any(|&k| self.free[k]) || inside(self, c);
        }
    }

    /// Every grid square, by its lower-left point.
    fn squares(&self) -> impl Iterator<Item = Cell> + use<> {
        let (nx, nz) = (self.nx, self.nz);
        (0..nx * nz).filter(move |&c| c % nx + 1 < nx && c / nx + 1 < nz)
    }

    /// The four grid points of the square whose lower-left point is `c`.
    fn square_corners(&self, c: Cell) -> [Cell; 4] {
        [c, c + 1, c + self.nx, c + self.nx + 1]
    }

    /// An `nx`×`nz` grid of `step` from the origin whose point (col, row) is free where `free`
    /// says (grids drawn by hand, for tests).
    pub fn from_mask(step: f32, nx: usize, nz: usize, free: impl Fn(usize, usize) -> bool) -> NavGrid {
        let free = (0..nx * nz).map(|c| free(c % nx, c / nx)).collect();
        let mut g = NavGrid { step, i0: 0, k0: 0, nx, nz, free, passable: vec![false; nx * nz] };
        // without a scene to ask, a square is passable where a corner is free
        g.mark_passable(|_, _| false);
        g
    }

    pub fn len(&self) -> usize {
        self.nx * self.nz
    }

    pub fn is_empty(&self) -> bool {
        self.free.iter().all(|f| !f)
    }

    pub fn point(&self, c: Cell) -> Point2<f32> {
        let (col, row) = ((c % self.nx) as i32, (c / self.nx) as i32);
        Point2::new((self.i0 + col) as f32 * self.step, (self.k0 + row) as f32 * self.step)
    }

    pub fn is_free(&self, c: Cell) -> bool {
        self.free[c]
    }

    /// Free cells.
    pub fn free_cells(&self) -> impl Iterator<Item = Cell> + '_ {
        (0..self.len()).filter(|&c| self.free[c])
    }

    /// The cell whose point is nearest to `p`, if `p` lies on the grid's extent.
    pub fn cell_at(&self, p: Point2<f32>) -> Option<Cell> {
        let col = (p.x / self.step).round() as i32 - self.i0;
        let row = (p.y / self.step).round() as i32 - self.k0;
        (col >= 0 && row >= 0 && (col as usize) < self.nx && (row as usize) < self.nz)
            .then(|| row as usize * self.nx + col as usize)
    }

    /// The square holding `p` (between four grid points), by its lower-left point.
    fn square_at(&self, p: Point2<f32>) -> Option<Cell> {
        let col = (p.x / self.step).floor() as i32 - self.i0;
        let row = (p.y / self.step).floor() as i32 - self.k0;
        (col >= 0 && row >= 0 && (col as usize) + 1 < self.nx && (row as usize) + 1 < self.nz)
            .then(|| row as usize * self.nx + col as usize)
    }

    /// Whether `p` lies in a passable grid square, its edges and corners included (a point on
    /// an edge belongs to both squares beside it, a grid point to all four around it).
    pub fn square_passable(&self, p: Point2<f32>) -> bool {
        let e = 1e-4 * self.step;
        [(-e, -e), (e, -e), (-e, e), (e, e)]
            .iter()
            .any(|&(dx, dz)| self.square_at(p + Vector2::new(dx, dz)).is_some_and(|c| self.passable[c]))
    }

    /// Whether grid point `c` is a corner of a passable square: the places where shortest
    /// paths through the passable squares can bend.
    pub fn is_corner_of_passable(&self, c: Cell) -> bool {
        let (col, row) = (c % self.nx, c / self.nx);
        [(0, 0), (1, 0), (0, 1), (1, 1)].iter().any(|&(dc, dr)| {
            col >= dc && row >= dr && col - dc + 1 < self.nx && row - dr + 1 < self.nz && {
                self.passable[(row - dr) * self.nx + col - dc]
            }
        })
    }

    /// Marks cells within `radius` of `center` as blocked (the person standing there).
    pub fn block_disc(&mut self, center: Point2<f32>, radius: f32) {
        let inside = |g: &NavGrid, c: Cell| (g.point(c) - center).norm() < radius;
        for c in 0..self.len() {
            if inside(self, c) {
                self.free[c] = false;
            }
        }
        // a square all of whose corners are inside lies inside: the robot cannot be there
        for c in self.squares() {
            if self.square_corners(c).iter().all(|&k| inside(self, k)) {
                self.passable[c] = false;
            }
        }
    }

    /// Free neighbours of a cell with the cost of the step. Diagonal steps need both
    /// orthogonal neighbours free, so paths never cut a corner the capsule cannot pass.
    pub fn neighbours(&self, c: Cell) -> impl Iterator<Item = (Cell, f32)> + '_ {
        let (col, row) = ((c % self.nx) as i32, (c / self.nx) as i32);
        let at = move |dc: i32, dr: i32| -> Option<Cell> {
            let (cc, rr) = (col + dc, row + dr);
            (cc >= 0 && rr >= 0 && (cc as usize) < self.nx && (rr as usize) < self.nz)
                .then(|| rr as usize * self.nx + cc as usize)
                .filter(|&n| self.free[n])
        };
        const D: [(i32, i32); 8] = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)];
        D.iter().filter_map(move |&(dc, dr)| {
            let n = at(dc, dr)?;
            if dc != 0 && dr != 0 && (at(dc, 0).is_none() || at(0, dr).is_none()) {
                return None;
            }
            let cost = if dc != 0 && dr != 0 { self.step * std::f32::consts::SQRT_2 } else { self.step };
            Some((n, cost))
        })
    }

    /// Connected components of free cells (label per cell, usize::MAX for blocked) and the
    /// label of the largest one.
    pub fn components(&self) -> (Vec<usize>, Option<usize>) {
        let mut label = vec![usize::MAX; self.len()];
        let mut sizes = Vec::new();
        for s in self.free_cells() {
            if label[s] != usize::MAX {
                continue;
            }
            let id = sizes.len();
            let mut stack = vec![s];
            label[s] = id;
            let mut n = 0;
            while let Some(c) = stack.pop() {
                n += 1;
                for (m, _) in self.neighbours(c) {
                    if label[m] == usize::MAX {
                        label[m] = id;
                        stack.push(m);
                    }
                }
            }
            sizes.push(n);
        }
        let largest = (0..sizes.len()).max_by_key(|&i| (sizes[i], usize::MAX - i));
        (label, largest)
    }

    /// Free cells within `radius` (2D) of a point.
    pub fn cells_near(&self, p: Point2<f32>, radius: f32) -> Vec<Cell> {
        self.free_cells().filter(|&c| (self.point(c) - p).norm() < radius).collect()
    }
}

/// Geodesic distance from every cell to a set of goal cells (Dijkstra on the 8-connected grid).
#[derive(Clone, Debug)]
pub struct DistanceField {
    pub dist: Vec<f32>,
}

/// A cell and its distance in a Dijkstra queue: `BinaryHeap` pops the nearest first (ties by cell).
#[derive(PartialEq)]
pub(crate) struct Entry(pub f32, pub Cell);
impl Eq for Entry {}
impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.partial_cmp(&self.0).unwrap_or(Ordering::Equal).then(o.1.cmp(&self.1))
    }
}
impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

impl DistanceField {
    pub fn new(grid: &NavGrid, goals: &[Cell]) -> DistanceField {
        let sources: Vec<(Cell, f32)> = goals.iter().map(|&g| (g, 0.0)).collect();
        DistanceField::from_sources(grid, &sources)
    }

    /// Distance to the cheapest of `sources`, each reached at its own extra cost: the grid
    /// distance to a source cell plus that cell's cost (e.g. the straight stretch from a cell
    /// near a target to the target's centre).
    pub fn from_sources(grid: &NavGrid, sources: &[(Cell, f32)]) -> DistanceField {
        let mut dist = vec![f32::INFINITY; grid.len()];
        let mut heap = BinaryHeap::new();
        for &(g, cost) in sources {
            if grid.is_free(g) && cost < dist[g] {
                dist[g] = cost;
                heap.push(Entry(cost, g));
            }
        }
        while let Some(Entry(d, c)) = heap.pop() {
            if d > dist[c] {
                continue;
            }
            for (n, w) in grid.neighbours(c) {
                let nd = d + w;
                if nd < dist[n] {
                    dist[n] = nd;
                    heap.push(Entry(nd, n));
                }
            }
        }
        DistanceField { dist }
    }

    /// Distance at a cell (∞ when the goal cannot be reached from it).
    pub fn at_cell(&self, c: Cell) -> f32 {
        self.dist[c]
    }

    /// Distance at a continuous position: the best of the free grid points within 1.5 steps,
    /// plus the straight offset to that point.
    pub fn at(&self, grid: &NavGrid, p: Point2<f32>) -> f32 {
        let Some(c0) = grid.cell_at(p) else { return f32::INFINITY };
        let (col, row) = ((c0 % grid.nx) as i32, (c0 / grid.nx) as i32);
        let mut best = f32::INFINITY;
        for dr in -1..=1 {
            for dc in -1..=1 {
                let (cc, rr) = (col + dc, row + dr);
                if cc < 0 || rr < 0 || cc as usize >= grid.nx || rr as usize >= grid.nz {
                    continue;
                }
                let c = rr as usize * grid.nx + cc as usize;
                if !grid.is_free(c) {
                    continue;
                }
                let off = (grid.point(c) - p).norm();
                if off <= grid.step * 1.5 {
                    best = best.min(self.dist[c] + off);
                }
            }
        }
        best
    }
}

/// A target's success region and the distance field to it.
#[derive(Clone, Debug)]
pub struct Goal {
    /// Target centre.
    pub center: Point3<f32>,
    /// Instance id of the target.
    pub id: u16,
    /// Sample points on the target's parts, aimed at by visibility rays.
    pub points: Vec<Point3<f32>>,
    /// Free cells within the success distance from which the target is visible for some heading.
    pub cells: Vec<Cell>,
    pub field: DistanceField,
}

/// The success region's cells lie this much inside the success distance: the robot moves off
/// the grid (15° headings), and a cell right at the boundary would need it to stand exactly on
/// the grid point to count. Every pose within this margin of a region cell is a success pose.
pub const REGION_MARGIN: f32 = 0.1;

/// Radius around the target centre within which grid cells form the success region.
pub fn region_radius(success_distance: f32) -> f32 {
    (success_distance - REGION_MARGIN).max(0.0)
}

/// Headings the robot can face (multiples of the turn angle).
pub fn headings(turn_deg: f32) -> impl Iterator<Item = f32> {
    let n = (360.0 / turn_deg).round() as u32;
    (0..n).map(move |k| k as f32 * turn_deg)
}

impl Goal {
    /// Builds the success region and its distance field. The region holds free cells within
    /// `region_radius(success_distance)` (2D) of the centre from which the target is seen for
    /// some heading.
    pub fn new(
        grid: &NavGrid,
        physics: &Physics,
        env: &EnvConfig,
        k: &Intrinsics,
        success_distance: f32,
        center: Point3<f32>,
        id: u16,
        points: Vec<Point3<f32>>,
    ) -> Goal {
        let cells: Vec<Cell> = grid
            .cells_near(xz(&center).into(), region_radius(success_distance))
            .into_iter()
            .filter(|&c| {
                let p = grid.point(c);
                visible_headings(physics, env, k, p, &points, id).next().is_some()
            })
            .collect();
        let field = DistanceField::new(grid, &cells);
        Goal { center, id, points, cells, field }
    }

    /// Geodesic distance from a position to the success region (∞ if it cannot be reached).
    pub fn geodesic(&self, grid: &NavGrid, p: Point2<f32>) -> f32 {
        self.field.at(grid, p)
    }

    pub fn distance_2d(&self, p: Point2<f32>) -> f32 {
        (Vector2::new(self.center.x, self.center.z) - p.coords).norm()
    }
}

/// Headings (multiples of the turn angle) from which the target is seen at `p`.
pub fn visible_headings<'a>(
    physics: &'a Physics,
    env: &'a EnvConfig,
    k: &'a Intrinsics,
    p: Point2<f32>,
    points: &'a [Point3<f32>],
    id: u16,
) -> impl Iterator<Item = f32> + 'a {
    headings(env.turn_deg).filter(move |&yaw| {
        let cam = RobotPose { x: p.x, z: p.y, yaw }.camera(env);
        visibility::visible(physics, &cam, k, points, id)
    })
}

/// Whether the target is seen from a pose.
pub fn sees_goal(physics: &Physics, env: &EnvConfig, k: &Intrinsics, pose: &RobotPose, goal: &Goal) -> bool {
    let cam: Camera = pose.camera(env);
    visibility::visible(physics, &cam, k, &goal.points, goal.id)
}

/// The expert's next action: Stop when the target is near and seen; near the target, the first
/// action of the shortest action sequence to a success pose (a local search); otherwise turn
/// to (or step along) the heading whose step lowers the geodesic distance most.
///
/// `seen_now` is what the robot's rendered frame says about the target (None: judge it
/// geometrically). A frame smaller than the reference resolution can miss a small target that
/// geometry sees; the expert then steps closer, which makes it larger.
#[allow(clippy::too_many_arguments)]
pub fn expert_action(
    grid: &NavGrid,
    physics: &Physics,
    env: &EnvConfig,
    k: &Intrinsics,
    success_distance: f32,
    goal: &Goal,
    pose: &RobotPose,
    seen_now: Option<bool>,
) -> Action {
    let here = pose.xz();
    let d = goal.distance_2d(here);
    if d < success_distance + LOCAL_REACH {
        let seen_geo = sees_goal(physics, env, k, pose, goal);
        let seen = seen_now.unwrap_or(seen_geo);
        if d < success_distance && seen {
            return Action::Stop;
        }
        // Near the target, plan over the robot's own actions: off-grid poses and real
        // collisions count. When the frame misses a target that geometry sees (a small target
        // in a small frame), look for a closer pose, where it is larger.
        let closer_than = if d < success_distance && seen_geo { d - 0.5 * env.move_step } else { f32::INFINITY };
        if let Some(a) = local_plan(physics, env, k, success_distance, goal, pose, closer_than) {
            return a;
        }
    }
    // Step along the heading that lowers the distance most; turning costs a little so that
    // ties go to the current heading.
    let now = goal.geodesic(grid, here);
    let mut best: Option<(f32, f32)> = None;
    for yaw in headings(env.turn_deg) {
        let delta = heading(yaw) * env.move_step;
        let d = goal.geodesic(grid, here + delta);
        if !d.is_finite() || !physics.move_is_free(here, delta) {
            continue;
        }
        let turns = (angle_diff_deg(pose.yaw, yaw).abs() / env.turn_deg).round();
        let cost = d + 0.01 * turns;
        if best.is_none_or(|(c, _)| cost < c) {
            best = Some((cost, yaw));
        }
    }
    match best {
        Some((cost, yaw)) if cost < now + 0.01 * 12.0 => {
            if angle_diff_deg(pose.yaw, yaw).abs() < 1e-2 {
                Action::MoveAhead
            } else {
                turn_towards(pose.yaw, yaw)
            }
        }
        // No step lowers the geodesic distance: off the grid, next to the success region, every
        // step overshoots it (or the robot is boxed in). Face the target and step towards it
        // while that brings it closer.
        _ => {
            let to = goal.center - Point3::new(here.x, goal.center.y, here.y);
            let want = crate::geometry::yaw_of(Vector2::new(to.x, to.z));
            let delta = heading(pose.yaw) * env.move_step;
            let facing = angle_diff_deg(pose.yaw, want).abs() <= env.turn_deg / 2.0 + 1e-3;
            if facing && goal.distance_2d(here + delta) < goal.distance_2d(here) && physics.move_is_free(here, delta) {
                Action::MoveAhead
            } else {
                turn_towards(pose.yaw, want)
            }
        }
    }
}

/// How far outside the success distance the local search starts, and how deep it looks.
const LOCAL_REACH: f32 = 0.75;
const LOCAL_DEPTH: usize = 8;

/// Breadth-first search over the robot's own actions (so off-grid poses and real collisions
/// count) for the shortest action sequence to a pose within the success distance, closer than
/// `closer_than` to the target centre, from which the target is seen. Returns its first action.
fn local_plan(
    physics: &Physics,
    env: &EnvConfig,
    k: &Intrinsics,
    success_distance: f32,
    goal: &Goal,
    start: &RobotPose,
    closer_than: f32,
) -> Option<Action> {
    use std::collections::{HashSet, VecDeque};
    let key =
        |p: &RobotPose| ((p.x * 1000.0).round() as i64, (p.z * 1000.0).round() as i64, (p.yaw * 10.0).round() as i64);
    let mut seen = HashSet::from([key(start)]);
    let mut queue = VecDeque::from([(*start, None::<Action>, 0usize)]);
    while let Some((pose, first, depth)) = queue.pop_front() {
        if first.is_some() {
            let d = goal.distance_2d(pose.xz());
            if d < success_distance && d < closer_than && sees_goal(physics, env, k, &pose, goal) {
                return first;
            }
        }
        if depth == LOCAL_DEPTH {
            continue;
        }
        for a in [Action::MoveAhead, Action::RotateLeft, Action::RotateRight] {
            let mut next = pose;
            if !crate::robot::apply(&mut next, a, env, physics).moved && a == Action::MoveAhead {
                continue;
            }
            if seen.insert(key(&next)) {
                queue.push_back((next, first.or(Some(a)), depth + 1));
            }
        }
    }
    None
}

fn turn_towards(from: f32, to: f32) -> Action {
    if angle_diff_deg(from, to) > 0.0 { Action::RotateRight } else { Action::RotateLeft }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Part, Shape};
    use crate::physics::RobotBody;
    use crate::robot::apply;
    use crate::scene::{Room, Surface};
    use nalgebra::Vector3;

    fn room_with_divider() -> (Room, Vec<Part>) {
        let s = Surface { color: [0.5; 3], material: Default::default() };
        let room = Room { width: 6.0, depth: 6.0, height: 2.7, floor: s, walls: s, ceiling: s };
        let scene = crate::scene::Scene {
            name: "t".into(),
            scene_type: crate::scene::SceneType::Kitchen,
            seed: 0,
            room: room.clone(),
            walls: vec![crate::scene::WallSegment { from: [-3.0, 0.0], to: [1.5, 0.0], thickness: 0.1 }],
            objects: vec![],
        };
        let mut parts = scene.structure_parts();
        parts.push(
            Part::new(Shape::Box, Point3::new(-2.0, 0.9, 2.0), Vector3::new(0.1, 0.1, 0.1), [1.0, 0.0, 0.0]).with_id(7),
        );
        (room, parts)
    }

    fn setup() -> (NavGrid, Physics, Goal, EnvConfig, Intrinsics) {
        let (room, parts) = room_with_divider();
        let env = EnvConfig::default();
        let k = Intrinsics { width: 224, height: 224, fov_deg: env.fov_deg };
        let phys = Physics::new(&parts, RobotBody::default());
        let grid = NavGrid::build(&phys, &room, GRID_STEP);
        let target = parts.last().unwrap();
        let goal = Goal::new(&grid, &phys, &env, &k, 1.0, target.center, 7, target.sample_points().to_vec());
        (grid, phys, goal, env, k)
    }

    #[test]
    fn grid_keeps_clear_of_walls() {
        let (grid, _, _, _, _) = setup();
        for c in grid.free_cells() {
            let p = grid.point(c);
            assert!(p.x.abs() <= 3.0 - 0.3 && p.y.abs() <= 3.0 - 0.3, "{p:?}");
            // distance from the point to the divider box (x in [-3, 1.5], z in [-0.05, 0.05])
            let dx = (p.x - 1.5).max(0.0);
            let dz = (p.y.abs() - 0.05).max(0.0);
            assert!((dx * dx + dz * dz).sqrt() >= 0.3 - 1e-3, "cell {p:?} inside the divider");
        }
        let (_, largest) = grid.components();
        assert!(largest.is_some());
    }

    #[test]
    fn geodesic_is_at_least_euclidean() {
        let (grid, _, goal, _, _) = setup();
        assert!(!goal.cells.is_empty());
        for c in grid.free_cells() {
            let d = goal.field.at_cell(c);
            if !d.is_finite() {
                continue;
            }
            let p = grid.point(c);
            let nearest_goal = goal.cells.iter().map(|&g| (grid.point(g) - p).norm()).fold(f32::INFINITY, f32::min);
            assert!(d + 1e-4 >= nearest_goal, "geodesic {d} < euclidean {nearest_goal}");
        }
        // from below the divider the path must go round it
        let below = grid.cell_at(Point2::new(-2.0, -2.0)).unwrap();
        let straight = (grid.point(below) - Point2::new(-2.0, 2.0)).norm() - 1.0;
        assert!(goal.field.at_cell(below) > straight + 1.0);
    }

    #[test]
    fn expert_reaches_the_goal_from_every_start() {
        let (grid, phys, goal, env, k) = setup();
        let mut starts = 0;
        for c in grid.free_cells().step_by(3) {
            if !goal.field.at_cell(c).is_finite() {
                continue;
            }
            starts += 1;
            let p = grid.point(c);
            let mut pose = RobotPose { x: p.x, z: p.y, yaw: ((c * 7) % 24) as f32 * 15.0 };
            let mut ok = false;
            for _ in 0..100 {
                let a = expert_action(&grid, &phys, &env, &k, 1.0, &goal, &pose, None);
                if a == Action::Stop {
                    ok = goal.distance_2d(pose.xz()) < 1.0 && sees_goal(&phys, &env, &k, &pose, &goal);
                    break;
                }
                let m = apply(&mut pose, a, &env, &phys);
                assert!(!m.collided, "expert bumped into something at {pose:?}");
            }
            assert!(ok, "expert failed from {p:?}");
        }
        assert!(starts > 50);
    }
}
