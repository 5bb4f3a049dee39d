#!/usr/bin/env python3
"""End of a bag replay (launch/replay.launch): waits until `rosbag play --clock` has played the
whole bag and the map corrector has taken in every message, optionally runs ~optimize, saves the
corrected graph with ~save_graph, prints the error before/after (toro_score: chi2 at the odometry
poses vs the corrected ones, and the error against the truth when graph_to_bag wrote one), looks
up the robot's final corrected pose map -> base_link on /tf, and publishes a one-line result on
~result (latched) for tests.

Private parameters: bag (path, required), node (default /map_corrector), output_dir (the node's
graph_directory, absolute, default /tmp/toro_replay: ~save_graph takes a name relative to it),
output_name (default corrected.g2o: the graph saved in output_dir, with its .stamps), truth ('' = <bag stem>.truth.g2o if it exists), final_iterations
(default 20; 0 = none), odom_topic (default /odom: the finisher waits until the node has
received as many odometry messages as the bag has on it), settle_sec (default 0.5: the node's status must stay unchanged this long),
exit_when_done (default true: shut the launch down when done; false keeps rviz up).
"""
import os
import subprocess
import sys
import threading
import time

import rosbag
import rospy
import roslib.packages
import tf2_ros
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String
from toro_ros.srv import GetStatus, GraphFile, Optimize


def wait_for_bag_end(end_time):
    """Blocks until /clock comes within a second of the bag's last stamp (rosbag play need not
    publish a clock at exactly the last stamp)."""
    reached = threading.Event()

    def on_clock(msg):
        if msg.clock.to_sec() >= end_time - 1.0:
            reached.set()

    sub = rospy.Subscriber('/clock', Clock, on_clock)
    while not reached.wait(0.5):
        if rospy.is_shutdown():
            sys.exit(1)
    sub.unregister()


def wait_until_settled(get_status, settle_sec, odometry_in_bag):
    """Waits until the node has received the bag's odometry, its queue is empty and its counts
    stop changing."""
    last, since = None, time.monotonic()
    while not rospy.is_shutdown():
        s = get_status()
        now = (s.keyframes, s.constraints, s.odometry_messages, s.loop_closures_applied, s.queue_length)
        if now != last or s.queue_length > 0 or s.odometry_messages < odometry_in_bag:
            last, since = now, time.monotonic()
        elif time.monotonic() - since >= settle_sec:
            return s
        time.sleep(0.05)
    sys.exit(1)


def final_pose(buffer):
    try:
        t = buffer.lookup_transform('map', 'base_link', rospy.Time(0), rospy.Duration(2.0)).transform
        return t.translation.x, t.translation.y, t.translation.z
    except (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException) as e:
        rospy.logwarn('replay_finish: no map -> base_link on /tf: %s', e)
        return None


def score(output, truth):
    exe = roslib.packages.find_node('toro_ros', 'toro_score')
    if not exe:
        return 'toro_score not found (build the package)'
    args = [exe[0], output] + ([truth] if truth else [])
    done = subprocess.run(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True)
    return done.stdout.strip()


def main():
    rospy.init_node('replay_finish')
    bag = rospy.get_param('~bag')
    node = rospy.get_param('~node', '/map_corrector').rstrip('/')
    # ~save_graph takes a name relative to the node's graph_directory (replay.launch gives the node
    # output_dir as that directory), so the graph lands in output_dir.
    output_name = rospy.get_param('~output_name', 'corrected.g2o')
    output = os.path.join(os.path.abspath(rospy.get_param('~output_dir', '/tmp/toro_replay')), output_name)
    truth = rospy.get_param('~truth', '')
    stem = bag[:-4] if bag.endswith('.bag') else bag
    if not truth and os.path.exists(stem + '.truth.g2o'):
        truth = stem + '.truth.g2o'
    iterations = int(rospy.get_param('~final_iterations', 20))
    buffer = tf2_ros.Buffer(rospy.Duration(60.0))
    tf2_ros.TransformListener(buffer)  # also makes /tf subscribed for rosbag play --wait-for-subscribers
    result_pub = rospy.Publisher('~result', String, queue_size=1, latch=True)

    odom_topic = rospy.get_param('~odom_topic', '/odom')
    with rosbag.Bag(bag) as b:
        end_time = b.get_end_time()
        odometry_in_bag = b.get_message_count(topic_filters=[odom_topic])
    for name in ('get_status', 'optimize', 'save_graph'):
        rospy.wait_for_service(node + '/' + name)
    get_status = rospy.ServiceProxy(node + '/get_status', GetStatus)
    wait_for_bag_end(end_time)
    status = wait_until_settled(get_status, float(rospy.get_param('~settle_sec', 0.5)), odometry_in_bag)
    rospy.loginfo('replay_finish: bag played: %d keyframes, %d constraints, %d loop closures applied, %d refused',
                  status.keyframes, status.constraints, status.loop_closures_applied, status.loop_closures_refused)
    if iterations > 0:
        r = rospy.ServiceProxy(node + '/optimize', Optimize)(iterations, 'full')
        rospy.loginfo('replay_finish: ~optimize %d: chi2 %.6g -> %.6g (%s)', iterations, r.chi2_before,
                      r.chi2_after, r.message)
    saved = rospy.ServiceProxy(node + '/save_graph', GraphFile)(output_name)
    if not saved.success:
        rospy.logerr('replay_finish: ~save_graph failed: %s', saved.message)
        result_pub.publish(String('failed: ' + saved.message))
        sys.exit(1)
    print('replay_finish: corrected graph written to %s\n%s' % (output, score(output, truth)), flush=True)
    pose = final_pose(buffer)
    if pose:
        print('replay_finish: final corrected pose map -> base_link: %.3f %.3f %.3f' % pose, flush=True)
    result_pub.publish(String('saved %s' % output))
    if rospy.get_param('~exit_when_done', True):
        time.sleep(1.0)  # let the latched result reach subscribers
        rospy.signal_shutdown('replay done')
    else:
        rospy.spin()


if __name__ == '__main__':
    main()
