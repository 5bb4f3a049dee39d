# Writes the seeds of fuzz_loop_closure: serialised toro_ros/LoopClosure messages (one or more per
# file) around the target's odometry (a line from t = 100 s, 0.1 s per message, keyframes 0.5 m apart).
#   PYTHONPATH=<build>/devel/lib/python3/dist-packages python3 test/fuzz/make_loop_closure_seeds.py \
#       test/fuzz/corpus/loop_closure
import io, math, sys
import rospy
from toro_ros.msg import LoopClosure
out = sys.argv[1]
def lc(sf, st, idf=-1, idt=-1, x=0.0, y=0.0, yaw=0.0, cov=None, frame='map'):
    m = LoopClosure()
    m.header.frame_id = frame
    m.header.stamp = rospy.Time.from_sec(103.0)
    m.stamp_from = rospy.Time.from_sec(sf); m.stamp_to = rospy.Time.from_sec(st)
    m.id_from = idf; m.id_to = idt
    m.from_T_to.position.x = x; m.from_T_to.position.y = y
    m.from_T_to.orientation.z = math.sin(yaw / 2); m.from_T_to.orientation.w = math.cos(yaw / 2)
    m.covariance = cov if cov is not None else [0.0] * 36
    return m
def diag(t, r):
    c = [0.0] * 36
    for k in range(3): c[7 * k] = t; c[7 * (k + 3)] = r
    return c
def write(name, *msgs):
    b = io.BytesIO()
    for m in msgs: m.serialize(b)
    open(f'{out}/{name}', 'wb').write(b.getvalue())
write('by_stamp_valid', lc(100.0, 103.0, x=3.0, yaw=0.03, cov=diag(4e-4, 1e-4)))
write('by_id_valid', lc(0, 0, 0, 5, x=3.0, cov=diag(4e-4, 1e-4)))
write('zero_covariance', lc(100.5, 103.5, x=3.0))
asym = diag(4e-4, 1e-4); asym[1] = 1e-3
write('asymmetric_covariance', lc(100.5, 103.5, x=3.0, cov=asym))
indef = diag(4e-4, 1e-4); indef[35] = -1e-4
write('indefinite_covariance', lc(100.5, 103.5, x=3.0, cov=indef))
write('nan_pose', lc(100.5, 103.5, x=float('nan'), cov=diag(4e-4, 1e-4)))
write('future_stamp', lc(100.0, 104.5, x=4.5, cov=diag(4e-4, 1e-4)))
write('far_future_stamp', lc(100.0, 4.0e9, x=4.5, cov=diag(4e-4, 1e-4)))
write('unknown_stamp', lc(50.0, 103.0, x=4.5, cov=diag(4e-4, 1e-4)))
write('self_loop', lc(0, 0, 3, 3))
write('unknown_id', lc(0, 0, 0, 1000))
write('duplicate_and_mixed', lc(100.0, 103.0, x=3.0, cov=diag(4e-4, 1e-4)), lc(100.0, 103.0, x=3.0, cov=diag(4e-4, 1e-4)),
      lc(0, 0, 1, 4, x=2.0), lc(101.0, 104.2, x=3.2))
