//! Each scene type's recipe: what stands where, in the order its pieces are drawn (the order is
//! part of every room: it fixes the seed stream's draws).

use nalgebra::{Point2, Vector2};
use rand::Rng;
use rand::seq::IndexedRandom;

use super::{Layout, Wall, WallSpan, along, wall_of};
use crate::geometry::heading;
use crate::scene::{Category, Category::*, Object};

impl Layout<'_> {
    /// Counters along the main wall (an L sometimes), a dining table with chairs, food and
    /// cutlery on the counters and tables.
    pub(super) fn kitchen(&mut self, main: Wall) {
        let frac = self.rng.random_range(0.6..0.9);
        let mut hosts = self.counter_run(main, frac, true);
        if self.chance(0.6) {
            // an L: counters along an adjacent wall, starting past the first run's depth
            let side = main.adjacent()[self.rng.random_range(0..2)];
            let size = self.size(CounterTop);
            let len = side.length(&self.room);
            let u = -len / 2.0 + 0.7 + size[0] / 2.0;
            hosts.extend(self.against_wall_at(CounterTop, side, u, size));
        }
        if self.chance(0.9) {
            hosts.extend(self.table_with_chairs(1.0));
        }
        if self.chance(0.35) {
            self.against_wall(Chair, None);
        }
        if self.chance(0.55) {
            hosts.extend(self.against_wall(SideTable, None));
        }
        for _ in 0..self.rng.random_range(1..=2) {
            self.on_wall(Window, None);
        }
        self.on_wall(Door, Some(main.opposite()));
        let items = [Apple, Bread, ButterKnife, Cup, Fork, Knife, PaperTowelRoll, Plate, Potato, Spoon, Tomato];
        for c in items {
            if self.chance(0.75) {
                let n = if self.chance(0.4) { 2 } else { 1 };
                for _ in 0..n {
                    self.on_host(c, &hosts);
                }
            }
        }
        if self.chance(0.45) {
            self.on_host(RemoteControl, &hosts);
        }
    }

    /// A sofa facing a coffee table (a rug, arm chairs, side tables), a TV, a dining table,
    /// shelves and lamps, and what lies on them.
    pub(super) fn living_room(&mut self, main: Wall) {
        let mut hosts = self.sofa_corner(main);
        if self.chance(0.2) {
            self.against_wall(Sofa, None);
        }
        if self.chance(0.9) {
            if let Some(tv) =
                self.against_wall(TvStand, Some(main.opposite())).or_else(|| self.against_wall(TvStand, None))
            {
                hosts.push(tv);
                self.on_host(Television, &[tv]);
            }
        }
        if self.chance(0.5) {
            hosts.extend(self.table_with_chairs(0.9));
        }
        if self.chance(0.6) {
            hosts.extend(self.against_wall(Shelf, None));
        }
        if self.chance(0.7) {
            self.on_floor(FloorLamp, 0.35, 0.3);
        }
        if self.chance(0.5) {
            self.against_wall(Chair, None);
        }
        if self.chance(0.55) {
            self.on_floor(Box, 0.4, 0.3);
        }
        self.third_host(&mut hosts);
        for _ in 0..self.rng.random_range(1..=2) {
            self.on_wall(Window, None);
        }
        for _ in 0..self.rng.random_range(0..=2) {
            self.on_wall(Poster, None);
        }
        self.on_wall(Door, None);
        let items = [
            (Laptop, 0.6),
            (Newspaper, 0.6),
            (Plate, 0.45),
            (TissueBox, 0.6),
            (Box, 0.35),
            (DeskLamp, 0.3),
            (RemoteControl, 0.3),
        ];
        self.scatter(&items, &hosts);
    }

    /// The sofa against the main wall (or another), and what gathers round it. Its hosts.
    fn sofa_corner(&mut self, main: Wall) -> Vec<usize> {
        let mut hosts = Vec::new();
        let Some(s) = self.against_wall(Sofa, Some(main)).or_else(|| self.against_wall(Sofa, None)) else {
            return hosts;
        };
        let so = self.objects[s].clone();
        let n = heading(so.yaw);
        let size = self.size(CoffeeTable);
        let p = Point2::new(so.position[0], so.position[2]) + n * (so.size[2] / 2.0 + 0.55 + size[2] / 2.0);
        if self.chance(0.6) {
            let rs = self.size(Rug);
            self.push(Rug, [p.x, 0.005, p.y], so.yaw, [rs[0], 0.01, rs[2]], None);
        }
        if let Some(ct) = self.on_floor_at(CoffeeTable, p, so.yaw, size, 0.3) {
            hosts.push(ct);
            self.arm_chairs(p, n, size);
        }
        // side tables at the sofa's ends
        for side in [-1.0f32, 1.0] {
            if self.chance(0.5) {
                let st = self.size(SideTable);
                let sofa_wall = wall_of(so.yaw);
                let u_sofa = along(&self.room, sofa_wall, Point2::new(so.position[0], so.position[2]));
                let u = u_sofa + side * (so.size[0] / 2.0 + st[0] / 2.0 + 0.05);
                if let Some(i) = self.against_wall_at(SideTable, sofa_wall, u, st) {
                    hosts.push(i);
                    if self.chance(0.6) {
                        self.on_host(DeskLamp, &[i]);
                    }
                }
            }
        }
        hosts
    }

    /// Arm chairs at the ends of the coffee table at `p` (facing `n`, of `size`), facing it.
    fn arm_chairs(&mut self, p: Point2<f32>, n: Vector2<f32>, size: [f32; 3]) {
        for side in [-1.0f32, 1.0] {
            if self.chance(0.45) {
                let a = self.size(ArmChair);
                let tang = Vector2::new(n.y, -n.x);
                let q = p + tang * side * (size[0] / 2.0 + 0.45 + a[2] / 2.0);
                let yaw = crate::geometry::yaw_of(p - q);
                let yaw = (yaw / 90.0).round() * 90.0 % 360.0;
                self.on_floor_at(ArmChair, q, yaw, a, 0.3);
            }
        }
    }

    /// A bed with night tables, a dresser, a desk with its chair, and what lies on them.
    pub(super) fn bedroom(&mut self, main: Wall) {
        let mut hosts = self.bed_with_night_tables(main);
        if let Some(dr) = self.against_wall(Dresser, None) {
            hosts.push(dr);
            if self.chance(0.6) {
                self.on_host(Television, &[dr]);
            }
        }
        if self.chance(0.7) {
            hosts.extend(self.desk_with_chair());
        }
        if self.chance(0.4) {
            self.against_wall(Sofa, None);
        }
        if self.chance(0.5) {
            self.against_wall(Chair, None);
        }
        if self.chance(0.5) {
            self.on_floor(Box, 0.4, 0.3);
        }
        self.third_host(&mut hosts);
        for _ in 0..self.rng.random_range(1..=2) {
            self.on_wall(Poster, None);
        }
        for _ in 0..self.rng.random_range(1..=2) {
            self.on_wall(Window, None);
        }
        self.on_wall(Door, None);
        let items = [
            (AlarmClock, 0.35),
            (DeskLamp, 0.35),
            (Laptop, 0.3),
            (RemoteControl, 0.75),
            (TissueBox, 0.7),
            (Box, 0.45),
            (Television, 0.25),
        ];
        self.scatter(&items, &hosts);
    }

    /// The bed against the main wall (or another), a night table at either side. Its hosts.
    fn bed_with_night_tables(&mut self, main: Wall) -> Vec<usize> {
        let mut hosts = Vec::new();
        let Some(bed) = self.against_wall(Bed, Some(main)).or_else(|| self.against_wall(Bed, None)) else {
            return hosts;
        };
        let b = self.objects[bed].clone();
        let bed_wall = wall_of(b.yaw);
        let u_bed = along(&self.room, bed_wall, Point2::new(b.position[0], b.position[2]));
        for side in [-1.0f32, 1.0] {
            if self.chance(0.7) {
                let st = self.size(SideTable);
                let u = u_bed + side * (b.size[0] / 2.0 + st[0] / 2.0 + 0.05);
                if let Some(i) = self.against_wall_at(SideTable, bed_wall, u, st) {
                    hosts.push(i);
                    if self.chance(0.6) {
                        self.on_host(AlarmClock, &[i]);
                    }
                    if self.chance(0.5) {
                        self.on_host(DeskLamp, &[i]);
                    }
                }
            }
        }
        hosts
    }

    /// A desk against a wall with a chair before it and sometimes a laptop on it.
    fn desk_with_chair(&mut self) -> Option<usize> {
        let desk = self.against_wall(Desk, None)?;
        let d = self.objects[desk].clone();
        let n = heading(d.yaw);
        let size = self.size(Chair);
        let p = Point2::new(d.position[0], d.position[2]) + n * (d.size[2] / 2.0 + size[2] / 2.0 + 0.05);
        self.on_floor_at(Chair, p, crate::geometry::wrap_deg(d.yaw + 180.0), size, 0.0);
        if self.chance(0.7) {
            self.on_host(Laptop, &[desk]);
        }
        Some(desk)
    }

    /// A tub in a corner of the main wall, a toilet and a sink on two other walls, towels, and
    /// what lies on the sink.
    pub(super) fn bathroom(&mut self, main: Wall) {
        let mut hosts = Vec::new();
        self.tub_in_corner(main);
        let walls_left: Vec<Wall> = Wall::ALL.into_iter().filter(|w| *w != main).collect();
        let toilet_wall = *walls_left.choose(self.rng).unwrap();
        self.toilet_corner(toilet_wall);
        let sink_wall =
            *walls_left.iter().filter(|w| **w != toilet_wall).collect::<Vec<_>>().choose(self.rng).unwrap().to_owned();
        hosts.extend(self.sink_with_mirror(sink_wall));
        for _ in 0..(1 + self.chance(0.45) as usize) {
            if self.chance(0.9) {
                if let Some(th) = self.on_wall(TowelHolder, None) {
                    if self.chance(0.9) {
                        self.hang_on(Towel, th);
                    }
                }
            }
        }
        if self.chance(0.5) {
            hosts.extend(self.against_wall(SideTable, None));
        }
        if self.chance(0.7) {
            self.on_wall(Window, None);
        }
        self.on_wall(Door, None);
        self.scatter(&[(TissueBox, 0.6), (PaperTowelRoll, 0.5), (ToiletPaper, 0.35)], &hosts);
    }

    /// The tub fills a corner along the main wall, with a curtain or a glass door in front.
    fn tub_in_corner(&mut self, main: Wall) {
        let tub_size = self.size(Bathtub);
        let len = main.length(&self.room);
        let u = -len / 2.0 + tub_size[0] / 2.0 + 0.02;
        let Some(tub) = self.against_wall_at(Bathtub, main, u, tub_size) else { return };
        let tb = self.objects[tub].clone();
        let n = heading(tb.yaw);
        let front = Point2::new(tb.position[0], tb.position[2]) + n * (tb.size[2] / 2.0 + 0.03);
        let kind = if self.chance(0.55) { ShowerCurtain } else { ShowerDoor };
        let mut s = self.size(kind);
        s[0] = s[0].min(tb.size[0]);
        let y = s[1] / 2.0 + if kind == ShowerCurtain { 0.05 } else { 0.0 };
        let i = self.push(kind, [front.x, y, front.y], tb.yaw, s, Some(tub));
        let r = Layout::footprint(tb.yaw, front, [s[0], s[1], 0.06]);
        self.floor.push((r, i));
    }

    /// The toilet against `wall`, a paper hanger beside it (with paper, mostly), a plunger.
    fn toilet_corner(&mut self, wall: Wall) {
        let Some(toilet) = self.against_wall(Toilet, Some(wall)) else { return };
        let to = self.objects[toilet].clone();
        let u_t = along(&self.room, wall, Point2::new(to.position[0], to.position[2]));
        let side = if self.chance(0.5) { 1.0 } else { -1.0 };
        let hs = self.size(ToiletPaperHanger);
        let (ylo, yhi) = ToiletPaperHanger.wall_height().unwrap();
        let y = self.rng.random_range(ylo..=yhi);
        let uh = u_t + side * (to.size[0] / 2.0 + 0.2);
        let span = WallSpan { wall, u0: uh - hs[0] / 2.0, u1: uh + hs[0] / 2.0, y0: y - 0.05, y1: y + 0.05 };
        if self.wall_free(&span) && uh.abs() < wall.length(&self.room) / 2.0 - 0.15 {
            let p = wall.point(&self.room, uh, hs[2] / 2.0);
            let h = self.push(ToiletPaperHanger, [p.x, y, p.y], wall.yaw(), hs, None);
            self.wall_spans.push(span);
            if self.chance(0.85) {
                let tp = self.size(ToiletPaper);
                let q = p + heading(wall.yaw()) * (hs[2] / 2.0 + 0.01);
                self.push(ToiletPaper, [q.x, y - 0.02, q.y], wall.yaw(), tp, Some(h));
            }
        }
        if self.chance(0.6) {
            let ps = self.size(Plunger);
            let q = wall.point(&self.room, u_t - side * (to.size[0] / 2.0 + 0.15), 0.15);
            self.on_floor_at(Plunger, q, wall.yaw(), ps, 0.02);
        }
    }

    /// The sink against `wall` (or another), a mirror above it, a hand towel beside it.
    fn sink_with_mirror(&mut self, wall: Wall) -> Option<usize> {
        let sink = self.against_wall(Sink, Some(wall)).or_else(|| self.against_wall(Sink, None))?;
        let s: Object = self.objects[sink].clone();
        let w = wall_of(s.yaw);
        let u_s = along(&self.room, w, Point2::new(s.position[0], s.position[2]));
        let ms = self.size(Mirror);
        let span = WallSpan { wall: w, u0: u_s - ms[0] / 2.0, u1: u_s + ms[0] / 2.0, y0: 1.15, y1: 1.15 + ms[1] };
        if self.wall_free(&span) {
            let p = w.point(&self.room, u_s, ms[2] / 2.0);
            self.push(Mirror, [p.x, 1.15 + ms[1] / 2.0, p.y], w.yaw(), ms, None);
            self.wall_spans.push(span);
        }
        if self.chance(0.9) {
            if let Some(hh) = self.on_wall(HandTowelHolder, Some(w)).or_else(|| self.on_wall(HandTowelHolder, None)) {
                if self.chance(0.9) {
                    self.hang_on(HandTowel, hh);
                }
            }
        }
        Some(sink)
    }

    /// A dining table on the floor (`wall_gap` from the walls) with 2–4 chairs around it.
    fn table_with_chairs(&mut self, wall_gap: f32) -> Option<usize> {
        let tb = self.on_floor(DiningTable, wall_gap, 0.9)?;
        let n = self.rng.random_range(2..=4);
        self.chairs_around(tb, n);
        Some(tb)
    }

    /// A side table against a wall when fewer than three hosts stand in the room.
    fn third_host(&mut self, hosts: &mut Vec<usize>) {
        if hosts.len() < 3 {
            hosts.extend(self.against_wall(SideTable, None));
        }
    }

    /// Each item on one of `hosts` with its probability.
    fn scatter(&mut self, items: &[(Category, f64)], hosts: &[usize]) {
        for &(c, p) in items {
            if self.chance(p) {
                self.on_host(c, hosts);
            }
        }
    }
}
