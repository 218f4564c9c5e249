"""`cobot-calib replay BAG`: publish a bag's messages, like `ros2 bag play`.

Each topic goes out with the QoS it was recorded with (keep-last 1000), as the recorded
bytes, timed by the recorded receive stamps scaled by --rate (0 or max: as fast as possible;
DDS gives no back-pressure, so a subscriber slower than that loses what overflows its
history). Before starting it waits up to --wait-subscribers seconds until every topic has a
matched subscriber; after the last message, until reliable subscribers acknowledged it.
--window N: flow control for a consumer that publishes how many messages it has taken
(std_msgs/UInt64, a running count) on /bag_player/consumed: at most N messages out that it
has not counted, /clock held while it catches up (bags.player); nothing is lost to a subscriber
whose history holds N, whatever the load.

--check: replay a sample bag through the pipeline on a private ROS_DOMAIN_ID with /clock
(use_sim_time) and compare the result with the bag's expected.yaml; exit 0 when it matches,
else 1. A teach bag (bags/five_point_close) goes through joint_state_monitor and
user_frame_solver, calibrate_user_frame is re-run with the replayed captures: the frame within
1e-6 m / 1e-6 rad (api.replay_check). A repeatability-trial bag (bags/trial_close: it has
/cobot_calib/probe_averages) goes through proximity_sensor, every probe average the trial took
is rebuilt from the replayed distances and the ISO 9283 statistics recomputed: RP_i and RP_all
within 1e-6 m (api.replay_trial_check; --rate 2 unless given, at most 20). A landmark bag
(bags/landmark_multi_close) goes through landmark_detector, the frame within 1e-6 m / 1e-6 rad
(api.replay_landmark_check). A sphere bag (bags/iiwa_spheres: only /cobot_calib/captures) is
identified again from its captures, every parameter within 1e-9 of expected.json
(api.replay_sphere_check).
"""
from __future__ import annotations

import sys

from cobot_calib_ros.cli.common import EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, fail

NODE_NAME = 'bag_player'
KINDS = ('a teach bag (/joint_states and /cobot_calib/captures, bags/five_point_close)',
         'a trial bag (/cobot_calib/probe_averages, bags/trial_close)',
         'a landmark bag (camera images and /cobot_calib/captures, bags/landmark_multi_close)',
         'a sphere bag (only /cobot_calib/captures, bags/iiwa_spheres)')


def _rate(text: str) -> float:
    import argparse
    if text.strip().lower() == 'max':
        return 0.0
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a rate: {text!r} (a factor like 2, or max)') \
            from None
    if not value >= 0:
        raise argparse.ArgumentTypeError('rate must be >= 0 (0 or max: as fast as possible)')
    return value


def add_parser(subparsers):
    p = subparsers.add_parser('replay', help='publish a bag\'s messages, like ros2 bag play',
                              description=__doc__ + ' Uses the exported ROS_DOMAIN_ID.')
    p.add_argument('bag', metavar='BAG', help='bag directory, or a .mcap/.db3 file')
    p.add_argument('--rate', type=_rate, default=None, metavar='R',
                   help='speed factor (default 1; 2 for --check of a trial bag); 0 or max: '
                        'as fast as possible')
    p.add_argument('--loop', action='store_true', help='start over at the end, until Ctrl-C')
    p.add_argument('--topics', nargs='+', metavar='TOPIC', help='play only these topics')
    p.add_argument('--clock', nargs='?', type=float, const=40.0, default=None, metavar='HZ',
                   help='publish /clock from the recorded stamps, HZ times per second of wall '
                        'time (default 40)')
    p.add_argument('--start-paused', action='store_true',
                   help=f'wait for a call to /{NODE_NAME}/resume (std_srvs/srv/Trigger)')
    p.add_argument('--wait-subscribers', type=float, default=2.0, metavar='SECONDS',
                   help='longest wait for subscribers to match before playing (default 2)')
    p.add_argument('--window', type=int, default=0, metavar='N',
                   help='flow control: at most N messages published that the consumer has '
                        f'not counted on /{NODE_NAME}/consumed (std_msgs/msg/UInt64, its '
                        'running count); default 0: none, as ros2 bag play')
    p.add_argument('--check', action='store_true',
                   help='check a sample bag (every one under bags/) against its expected '
                        'result: a teach or landmark bag\'s frame (1e-6 m / 1e-6 rad), a '
                        'trial bag\'s RP_i and RP_all (1e-6 m), replayed through the pipeline '
                        '(own domain, sim time); a sphere bag\'s identified parameters (1e-9, '
                        'expected.json); exit 0 if it matches, else 1')
    p.add_argument('--recapture', action='store_true',
                   help='with --check: average each hold again with capture_joints on the '
                        'replayed /clock instead of using the recorded means (needs a finite '
                        '--rate; a /clock of 1000 Hz unless --clock is given)')
    return p


def run(args) -> int:
    if getattr(args, 'check', False):
        return _check(args)
    if args.rate is None:
        args.rate = 1.0
    if getattr(args, 'recapture', False) and not args.check:
        return fail('replay: --recapture goes with --check', EXIT_USAGE)
    if args.clock is not None and not args.clock > 0:
        return fail('replay: --clock HZ must be > 0', EXIT_USAGE)
    if args.wait_subscribers < 0:
        return fail('replay: --wait-subscribers must be >= 0', EXIT_USAGE)
    if args.window < 0:
        return fail('replay: --window must be >= 0 (0: no flow control)', EXIT_USAGE)
    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.bags.reader import open_bag
    try:
        bag = open_bag(args.bag)
    except BagError as exc:
        return fail(f'replay: {exc}')
    with bag:
        for warning in bag.warnings:
            print(f'warning: {warning}', file=sys.stderr, flush=True)
        return _replay(bag, args)


def _replay(bag, args) -> int:
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.bags.player import BagPlayer, spinning
    from cobot_calib_ros.ros.session import client_ros_args
    from cobot_calib_ros.ros.time import ns_to_s

    def say(text: str) -> None:
        print(text, flush=True)

    rclpy.init(args=client_ros_args(), signal_handler_options=SignalHandlerOptions.NO)
    player = None
    try:
        player = BagPlayer(bag, rate=args.rate, loop=args.loop, topics=args.topics,
                           clock_hz=args.clock, start_paused=args.start_paused,
                           wait_subscribers=args.wait_subscribers, window=args.window,
                           report=say)
        count = sum(bag.topics[t].count for t in player.topics)
        speed = 'as fast as possible' if args.rate == 0 else f'at {args.rate:g}x'
        say(f'replaying {bag.path}: {count} messages on {len(player.topics)} topics, '
            f'{ns_to_s(bag.duration_ns):.3f} s recorded, {speed}'
            + (', looping' if args.loop else '') + ' (Ctrl-C to stop)')
        if not args.window:
            say(f'no --window: a subscriber slower than the replay loses what overflows its '
                f'history; the lost are counted if it publishes its count on /{NODE_NAME}/'
                'consumed (--window N: lossless for such a subscriber)')
        with spinning(player):
            try:
                result = player.play()
            except KeyboardInterrupt:
                player.stop()
                return fail('replay interrupted', EXIT_INTERRUPTED)
        say(f'published {result.published} messages in {result.wall_s:.3f} s '
            f'({result.speed:.2f}x real time)')
        if args.window:
            say(f'flow control: {result.resent} sent again before the first was counted, '
                f'{result.written_off} never counted on /{NODE_NAME}/consumed')
        elif result.lost is not None:
            say(f'lost: {result.lost} of {result.published} (not counted on '
                f'/{NODE_NAME}/consumed)')
        else:
            say(f'lost: not known (no count on /{NODE_NAME}/consumed)')
        if result.unacknowledged:
            return fail('replay: subscribers did not acknowledge the last messages on '
                        + ', '.join(result.unacknowledged))
        return EXIT_OK
    except BagError as exc:
        return fail(f'replay: {exc}')
    finally:
        if player is not None:
            player.destroy_node()
        rclpy.try_shutdown()


def _check(args) -> int:
    if args.loop or args.start_paused or args.topics or args.window:
        return fail('replay --check: --loop, --start-paused, --topics and --window do not '
                    'apply', EXIT_USAGE)
    if args.clock is not None and not args.clock > 0:
        return fail('replay: --clock HZ must be > 0', EXIT_USAGE)
    from cobot_calib_ros.api import (replay_check, replay_landmark_check, replay_sphere_check,
                                     replay_trial_check)
    from cobot_calib_ros.bags.errors import BagError
    from cobot_calib_ros.bags.reader import open_bag
    try:
        with open_bag(args.bag) as bag:
            trial = replay_trial_check.is_trial_bag(bag)
            landmark = replay_landmark_check.is_landmark_bag(bag)
            spheres = replay_sphere_check.is_sphere_bag(bag)
            teach = replay_check.is_teach_bag(bag)
    except BagError as exc:
        return fail(f'replay --check: {exc}')
    if trial:
        return _check_trial(args)
    if landmark:
        return _check_landmarks(args)
    if spheres:
        return _check_spheres(args)
    if not teach:
        return fail(f'replay --check: {args.bag} is none of the sample bags --check knows: '
                    + '; '.join(KINDS), EXIT_USAGE)
    if args.rate is None:
        args.rate = 1.0
    if args.recapture and args.rate == 0:
        return fail('replay --check --recapture: needs a finite --rate (the holds are '
                    'averaged again on the replayed /clock)', EXIT_USAGE)
    from cobot_calib_ros.api import replay_check
    from cobot_calib_ros.bags.errors import BagError

    def say(text: str) -> None:
        print(text, flush=True)
    try:
        result = replay_check.run_check(args.bag, rate=args.rate, say=say,
                                        clock_hz=args.clock or (1000.0 if args.recapture
                                                                else 40.0),
                                        recapture=args.recapture)
    except (replay_check.CheckError, BagError) as exc:
        return fail(f'replay --check: {exc}')
    except KeyboardInterrupt:
        return fail('replay --check interrupted', EXIT_INTERRUPTED)
    if result:
        say(f'check passed in {result.wall_s:.1f} s')
        return EXIT_OK
    print('check FAILED: the replayed frame differs from the expected one\n'
          f'  replayed T_base_user (rms {result.rms_replayed * 1e3:.4f} mm):\n'
          + replay_check.format_matrix(result.T_replayed)
          + '\n  expected T_base_user:\n' + replay_check.format_matrix(result.T_expected)
          + f'\n  translation differs by {result.translation_m * 1e3:.6f} mm, rotation by '
          f'{result.rotation_rad * 1e3:.6f} mrad (tolerance 1e-06 m, 1e-06 rad); '
          'replayed - expected xyz: ('
          + ', '.join(f'{v * 1e3:+.6f}' for v in result.T_replayed[:3, 3]
                      - result.T_expected[:3, 3]) + ') mm', file=sys.stderr, flush=True)
    return 1


def _check_rate(args, check, kind: str, checked_from: str, why: str) -> float | int:
    """The --rate of a trial or landmark bag's check (its DEFAULT_RATE when not given), or the
    usage exit code after a one-line error: --recapture, or a rate outside (0, MAX_RATE]."""
    if args.recapture:
        return fail(f'replay --check: --recapture is for a teach bag (capture_joints); a {kind} '
                    f'bag {checked_from}', EXIT_USAGE)
    rate = float(check.DEFAULT_RATE if args.rate is None else args.rate)
    if not 0 < rate <= check.MAX_RATE:
        return fail(f'replay --check: a {kind} bag replays at a finite --rate up to '
                    f'{check.MAX_RATE:g} ({why}); got {"max" if rate == 0 else f"{rate:g}"}',
                    EXIT_USAGE)
    return rate


def _check_landmarks(args) -> int:
    """--check of a landmark-session bag (api.replay_landmark_check)."""
    from cobot_calib_ros.api import replay_landmark_check as check
    from cobot_calib_ros.bags.errors import BagError
    rate = _check_rate(args, check, 'landmark', 'is checked from its images',
                       'landmark_detector keeps only the newest image')
    if isinstance(rate, int):
        return rate
    try:
        result = check.check(args.bag, rate, say=lambda text: print(text, flush=True))
    except (check.CheckError, BagError) as exc:
        return fail(f'replay --check: {exc}')
    except KeyboardInterrupt:
        return fail('replay --check interrupted', EXIT_INTERRUPTED)
    if result:
        return EXIT_OK
    print(result.report, file=sys.stderr, flush=True)
    return 1


def _check_spheres(args) -> int:
    """--check of a sphere-coupling bag (api.replay_sphere_check): identified offline."""
    from cobot_calib_ros.api import replay_sphere_check as check
    from cobot_calib_ros.bags.errors import BagError
    if args.recapture or args.rate is not None or args.clock is not None:
        return fail('replay --check: a sphere bag is identified from its captures, not '
                    'replayed: --rate, --clock and --recapture do not apply', EXIT_USAGE)
    try:
        result = check.run_check(args.bag, say=lambda text: print(text, flush=True))
    except (check.CheckError, BagError) as exc:
        return fail(f'replay --check: {exc}')
    if result:
        print(f'check passed in {result.wall_s:.1f} s', flush=True)
        return EXIT_OK
    print('check FAILED: the identification differs from the expected one\n  '
          + result.report, file=sys.stderr, flush=True)
    return 1


def _check_trial(args) -> int:
    """--check of a repeatability-trial bag (api.replay_trial_check)."""
    from cobot_calib_ros.api import replay_trial_check as check
    from cobot_calib_ros.bags.errors import BagError
    rate = _check_rate(args, check, 'trial', 'is checked from its probe voltages',
                       'proximity_sensor takes probe/voltage best effort')
    if isinstance(rate, int):
        return rate

    def say(text: str) -> None:
        print(text, flush=True)
    try:
        result = check.run_check(args.bag, rate=rate, say=say, clock_hz=args.clock or 40.0)
    except (check.CheckError, BagError) as exc:
        return fail(f'replay --check: {exc}')
    except KeyboardInterrupt:
        return fail('replay --check interrupted', EXIT_INTERRUPTED)
    if result:
        say(f'check passed in {result.wall_s:.1f} s')
        return EXIT_OK
    lines = ['check FAILED: the replayed repeatability differs from the expected one',
             f'  replayed RP_i {check.format_rp(result.rp_replayed)}, '
             f'RP_all {result.rp_all_replayed * 1e3:.6f} mm',
             f'  expected RP_i {check.format_rp(result.rp_expected)}, '
             f'RP_all {result.rp_all_expected * 1e3:.6f} mm']
    if result.rp_recorded is not None:
        lines.append(f'  recorded RP_i {check.format_rp(result.rp_recorded)}, '
                     f'RP_all {result.rp_all_recorded * 1e3:.6f} mm ({check.STATS_TOPIC})')
    lines.append(f'  largest difference {result.worst_m * 1e3:.6f} mm (tolerance '
                 f'{check.TOL_M * 1e3:g} mm)')
    print('\n'.join(lines), file=sys.stderr, flush=True)
    return 1
